//! Neural-network numerics shared by the policies, independent of what the networks
//! compute: dual numbers for exact forward-mode derivatives ([`scalar`]) and dense
//! multilayer perceptrons with a portable and an AVX2/FMA kernel ([`mlp`]).

pub mod mlp;
pub mod scalar;
