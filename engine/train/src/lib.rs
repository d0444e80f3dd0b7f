//! # ciflow-train
//!
//! Exact maximum-likelihood training of the policies in `ciflow_engine::flow`, with tch.
//! This crate is the only one in the workspace that links libtorch: inference, the
//! environments, the bridge and the Python extension never load it.
