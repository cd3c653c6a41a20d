//! Metalens imaging model.
