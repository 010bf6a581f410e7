//! Board localization (being written).
