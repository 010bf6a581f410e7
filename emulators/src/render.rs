//! Frame renderer (being written).
