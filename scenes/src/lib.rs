//! Scene captures: LLFF, COLMAP, splits.
