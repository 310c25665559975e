//! Retargeting (placeholder while writing)
