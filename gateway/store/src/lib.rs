//! SQLite persistence of the service (being built; see issue 15).
