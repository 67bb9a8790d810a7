//! revisit-eval (see ARCHITECTURE.md).
