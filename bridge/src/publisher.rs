//! [`CheckpointPublisher`]: how a trainer hands each new checkpoint to running engines,
//! which hot-load it without a restart (`ciflow/v2/policies/<name>/checkpoint`).

use std::path::Path;

use ciflow_engine::flow::checkpoint::{self, CONFIG_FILE, WEIGHTS_FILE};
use zenoh::Wait;
use zenoh::pubsub::Publisher;
use zenoh::qos::CongestionControl;

use crate::config::{NetworkOptions, Role};
use crate::error::{BridgeError, check_name};
use crate::protocol::keys;
use crate::protocol::{ByteBuf, CheckpointMsg, PROTOCOL_VERSION, encode};
use crate::signing::CheckpointSigner;
use ciflow_envs::registry::Kwargs;

/// Publishes the checkpoints of one policy name.
pub struct CheckpointPublisher {
    /// Keeps the Zenoh session open: dropping its last handle closes it.
    _session: zenoh::Session,
    name: String,
    kwargs: Kwargs,
    signer: Option<CheckpointSigner>,
    publisher: Publisher<'static>,
}

impl CheckpointPublisher {
    /// Joins Zenoh as a client (the default endpoint unless `network` says otherwise) and
    /// declares the publisher of policy `name`.
    pub fn open(network: &NetworkOptions, name: &str) -> Result<Self, BridgeError> {
        let session = network.open(
            Role::Client,
            "join Zenoh to publish checkpoints",
            "is an engine or router listening?",
        )?;
        Self::new(&session, name)
    }

    /// A publisher on an open Zenoh session.
    pub fn new(session: &zenoh::Session, name: &str) -> Result<Self, BridgeError> {
        check_name("policy name", name)?;
        let publisher = session
            .declare_publisher(keys::policy_checkpoint(name))
            // Every checkpoint matters: wait for the network rather than drop one.
            .congestion_control(CongestionControl::Block)
            .wait()
            .map_err(BridgeError::zenoh("declaring the checkpoint publisher"))?;
        Ok(Self {
            _session: session.clone(),
            name: name.to_owned(),
            kwargs: Kwargs::new(),
            signer: None,
            publisher,
        })
    }

    /// The task's construction arguments the checkpoints were trained with (e.g.
    /// `{obstacles: 1}`), sent with every publication. Without them, an engine keeps the
    /// arguments of the policy being replaced, or uses the task's defaults.
    pub fn with_kwargs(mut self, kwargs: Kwargs) -> Self {
        self.kwargs = kwargs;
        self
    }

    /// Signs every publication with `signer`, for engines that load only signed ones.
    pub fn with_signer(mut self, signer: Option<CheckpointSigner>) -> Self {
        self.signer = signer;
        self
    }

    pub fn name(&self) -> &str {
        &self.name
    }

    /// Publishes the checkpoint directory `dir` (`config.json` + `weights.safetensors`).
    /// Engines that serve its task swap their policy of this name for it.
    pub fn publish(&self, dir: &Path, epoch: u64, validation_nll: f64) -> Result<(), BridgeError> {
        let read = |file: &str| {
            let path = dir.join(file);
            std::fs::read(&path).map_err(|source| BridgeError::ReadCheckpoint { path, source })
        };
        let config = String::from_utf8(read(CONFIG_FILE)?).map_err(|source| {
            BridgeError::CheckpointNotUtf8 {
                path: dir.join(CONFIG_FILE),
                source,
            }
        })?;
        let task = checkpoint::parse_config(&config)
            .map_err(|source| BridgeError::CheckpointConfig {
                dir: dir.to_path_buf(),
                source,
            })?
            .task()
            .to_owned();
        let mut message = CheckpointMsg {
            v: PROTOCOL_VERSION,
            name: self.name.clone(),
            task,
            config,
            weights: ByteBuf::from(read(WEIGHTS_FILE)?),
            epoch,
            validation_nll,
            kwargs: self.kwargs.clone(),
            signature: None,
        };
        if let Some(signer) = &self.signer {
            signer.sign(&mut message);
        }
        self.publisher
            .put(encode(&message))
            .wait()
            .map_err(BridgeError::zenoh("publishing the checkpoint"))
    }
}
