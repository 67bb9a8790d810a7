//! revisit-store (see ARCHITECTURE.md).
