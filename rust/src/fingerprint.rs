//! TODO(owner): see issue. Placeholder module; replaced by its implementation.
