//! Python extension `ciflow._native` (built by maturin).
