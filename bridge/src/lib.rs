//! # ciflow-bridge
//!
//! The Zenoh server and wire protocol that expose every `ciflow-envs` task as a
//! Gymnasium environment.
//!
//! - [`protocol`]: key expressions, MessagePack messages and typed errors (version
//!   [`protocol::PROTOCOL_VERSION`]; `PROTOCOL.md` describes it for any language);
//! - [`server`]: [`EngineServer`], the engine hosting environment sessions;
//! - [`client`]: [`Client`] and [`RemoteEnv`], the Rust side of a Gymnasium client;
//! - [`config`]: Zenoh configuration with a zero-configuration loopback default;
//! - [`limits`]: the bounds an engine enforces per request, session and client;
//! - [`episodes`]: the episode channel, recorders publishing demonstrations to trainers;
//! - [`policy`]: the [`Policy`] hook for `act`; [`checkpoint_policy`]: trained
//!   checkpoints as policies; [`publisher`]: a trainer's checkpoint publications, which
//!   engines hot-load; [`signing`]: who may publish them;
//! - [`router`]: a Zenoh router in this process; [`access`]: the access-control rules it
//!   enforces (who may serve, own sessions and publish policies);
//! - [`spread`]: a closed-loop evaluation's episodes spread over many engines;
//! - [`vector`]: one vector environment over sessions on several engines;
//! - [`scheduling`]: an engine process as a batch job that yields to its clients.

pub mod access;
pub mod checkpoint_policy;
pub mod client;
pub mod config;
pub mod control;
pub mod episodes;
pub mod error;
pub mod limits;
pub mod policy;
pub mod protocol;
pub mod publisher;
pub mod query;
mod retry;
pub mod router;
pub mod scheduling;
pub mod server;
pub mod signing;
pub mod spread;
pub mod task_factory;
pub mod vector;

pub use access::AccessPolicy;
pub use checkpoint_policy::{CheckpointPolicy, PolicyLoadError};
pub use ciflow_envs::registry::Kwargs;
pub use client::{BatchStep, BatchStepOut, Client, EngineInfo, RemoteEnv, StepResult};
pub use config::{
    DEFAULT_ENDPOINT, DEFAULT_ENDPOINT_VARIABLE, Mode, NetworkOptions, Role, default_endpoint,
};
pub use control::{ANY_ENGINE, SessionControl, SourcedTelemetry, TelemetryStream};
pub use episodes::{CollectError, EpisodePublisher, EpisodeSubscriber};
pub use error::BridgeError;
pub use limits::{Limits, Usage};
pub use policy::{Policy, PolicyError};
pub use protocol::BatchSeeds;
pub use publisher::CheckpointPublisher;
pub use query::query_all;
pub use router::Router;
pub use server::{EngineServer, ServerOptions};
pub use signing::{CheckpointSigner, KeyError, SignatureRefused, TrustedKeys};
pub use task_factory::TaskFactory;
/// The Zenoh crate this bridge is built with, for callers that need its types.
pub use zenoh;
