//! revisit-synth (see ARCHITECTURE.md).
