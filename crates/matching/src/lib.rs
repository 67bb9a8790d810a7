//! revisit-matching (see ARCHITECTURE.md).
