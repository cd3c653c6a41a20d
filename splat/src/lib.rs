//! Differentiable Gaussian-splat rasterizer.
