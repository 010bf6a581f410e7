//! The service (being built; see issue 15).
