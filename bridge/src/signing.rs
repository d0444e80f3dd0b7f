//! Signed checkpoint publications: a trainer signs each checkpoint it publishes with its
//! ed25519 key; an engine given trusted keys hot-loads only checkpoints one of them signed.
//!
//! The signature covers [`signed_bytes`]: the whole message (name, task, configuration,
//! weights, epoch, score, arguments) and the signer's public key, so nothing can be
//! swapped under a valid signature. Keys are standard PEM files, made with
//! standard tools:
//!
//! ```text
//! openssl genpkey -algorithm ed25519 -out trainer.pem              # the trainer's, secret
//! openssl pkey -in trainer.pem -pubout -out trainer.pub.pem       # given to engines
//! ```

use std::path::{Path, PathBuf};

use ed25519_dalek::pkcs8::{DecodePrivateKey, DecodePublicKey};
use ed25519_dalek::{Signature, Signer, SigningKey, Verifier, VerifyingKey};
use serde_bytes::ByteBuf;

use crate::protocol::{CheckpointMsg, CheckpointSignature, encode};

/// A key file that cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum KeyError {
    #[error("cannot read the ed25519 private key {} (PKCS#8 PEM, as `openssl genpkey -algorithm ed25519` writes it)", path.display())]
    Private {
        path: PathBuf,
        #[source]
        source: ed25519_dalek::pkcs8::Error,
    },
    #[error("cannot read the ed25519 public key {} (PEM, as `openssl pkey -pubout` writes it)", path.display())]
    Public {
        path: PathBuf,
        #[source]
        source: ed25519_dalek::pkcs8::spki::Error,
    },
}

/// Why an engine that trusts keys refused a publication.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum SignatureRefused {
    #[error("the checkpoint is not signed, and this engine loads only signed checkpoints")]
    Unsigned,
    #[error("the checkpoint is signed by key {0}, which this engine does not trust")]
    UntrustedKey(String),
    #[error("the checkpoint's signature does not match its content")]
    Invalid,
}

/// A trainer's signing key.
pub struct CheckpointSigner(SigningKey);

impl CheckpointSigner {
    /// Reads a PKCS#8 PEM private key.
    pub fn from_pem_file(path: &Path) -> Result<Self, KeyError> {
        SigningKey::read_pkcs8_pem_file(path)
            .map(Self)
            .map_err(|source| KeyError::Private {
                path: path.to_owned(),
                source,
            })
    }

    /// The key of a 32-byte secret seed.
    pub fn from_seed(seed: &[u8; 32]) -> Self {
        Self(SigningKey::from_bytes(seed))
    }

    pub fn verifying_key(&self) -> VerifyingKey {
        self.0.verifying_key()
    }

    /// Signs `message` in place (replacing any earlier signature).
    pub fn sign(&self, message: &mut CheckpointMsg) {
        message.signature = Some(CheckpointSignature {
            key: ByteBuf::from(self.0.verifying_key().to_bytes().to_vec()),
            signature: ByteBuf::new(),
        });
        let signature = self.0.sign(&signed_bytes(message));
        if let Some(signed) = &mut message.signature {
            signed.signature = ByteBuf::from(signature.to_bytes().to_vec());
        }
    }
}

/// The keys an engine accepts checkpoints from.
#[derive(Clone, Debug, Default)]
pub struct TrustedKeys(Vec<VerifyingKey>);

impl TrustedKeys {
    pub fn new(keys: Vec<VerifyingKey>) -> Self {
        Self(keys)
    }

    /// Reads PEM public keys, one per file.
    pub fn from_pem_files(paths: &[PathBuf]) -> Result<Self, KeyError> {
        paths
            .iter()
            .map(|path| {
                VerifyingKey::read_public_key_pem_file(path).map_err(|source| KeyError::Public {
                    path: path.clone(),
                    source,
                })
            })
            .collect::<Result<_, _>>()
            .map(Self)
    }

    /// Whether a trusted key signed exactly this message.
    pub fn verify(&self, message: &CheckpointMsg) -> Result<(), SignatureRefused> {
        let signed = message
            .signature
            .as_ref()
            .ok_or(SignatureRefused::Unsigned)?;
        let key = <[u8; 32]>::try_from(signed.key.as_slice())
            .ok()
            .and_then(|bytes| VerifyingKey::from_bytes(&bytes).ok())
            .ok_or(SignatureRefused::Invalid)?;
        if !self.0.contains(&key) {
            return Err(SignatureRefused::UntrustedKey(hex(&key.to_bytes())));
        }
        let signature =
            Signature::from_slice(&signed.signature).map_err(|_| SignatureRefused::Invalid)?;
        key.verify(&signed_bytes(message), &signature)
            .map_err(|_| SignatureRefused::Invalid)
    }
}

/// What a signature covers: the message encoded with its signature's `signature` bytes
/// left empty — every field, and the signer's key.
pub fn signed_bytes(message: &CheckpointMsg) -> Vec<u8> {
    let mut unsigned = message.clone();
    if let Some(signed) = &mut unsigned.signature {
        signed.signature = ByteBuf::new();
    }
    encode(&unsigned)
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// `ciflow train --signing-key`.
#[cfg(feature = "clap")]
#[derive(Clone, Debug, Default, clap::Args)]
pub struct SigningArgs {
    /// Sign every published checkpoint with this ed25519 private key (PKCS#8 PEM, e.g.
    /// from `openssl genpkey -algorithm ed25519`); engines started with its public key in
    /// `--trusted-key` load only checkpoints so signed.
    #[arg(long, value_name = "PEM", requires = "publish")]
    pub signing_key: Option<PathBuf>,
}

#[cfg(feature = "clap")]
impl SigningArgs {
    pub fn load(&self) -> Result<Option<CheckpointSigner>, KeyError> {
        self.signing_key
            .as_deref()
            .map(CheckpointSigner::from_pem_file)
            .transpose()
    }
}

/// `ciflow serve --trusted-key`.
#[cfg(feature = "clap")]
#[derive(Clone, Debug, Default, clap::Args)]
pub struct TrustArgs {
    /// Hot-load only checkpoints signed by this ed25519 public key (PEM; repeatable).
    /// Without it, any publication on the checkpoint keys is loaded.
    #[arg(long = "trusted-key", value_name = "PEM")]
    pub trusted_keys: Vec<PathBuf>,
}

#[cfg(feature = "clap")]
impl TrustArgs {
    pub fn load(&self) -> Result<Option<TrustedKeys>, KeyError> {
        if self.trusted_keys.is_empty() {
            return Ok(None);
        }
        TrustedKeys::from_pem_files(&self.trusted_keys).map(Some)
    }
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    use super::*;
    use crate::protocol::PROTOCOL_VERSION;

    fn message() -> CheckpointMsg {
        CheckpointMsg {
            v: PROTOCOL_VERSION,
            name: "avoid".into(),
            task: "obstacle-avoidance".into(),
            config: "{}".into(),
            weights: ByteBuf::from(vec![1, 2, 3]),
            epoch: 4,
            validation_nll: -1.5,
            kwargs: BTreeMap::from([("obstacles".to_owned(), 1.0.into())]),
            signature: None,
        }
    }

    #[test]
    fn only_a_trusted_key_s_signature_of_the_exact_message_passes() {
        let trainer = CheckpointSigner::from_seed(&[7; 32]);
        let attacker = CheckpointSigner::from_seed(&[9; 32]);
        let trusted = TrustedKeys::new(vec![trainer.verifying_key()]);

        let mut signed = message();
        trainer.sign(&mut signed);
        assert_eq!(trusted.verify(&signed), Ok(()));
        // The signature survives the wire.
        let received: CheckpointMsg =
            rmp_serde::from_slice(&crate::protocol::encode(&signed)).unwrap();
        assert_eq!(trusted.verify(&received), Ok(()));

        assert_eq!(trusted.verify(&message()), Err(SignatureRefused::Unsigned));
        let mut forged = message();
        attacker.sign(&mut forged);
        assert!(matches!(
            trusted.verify(&forged),
            Err(SignatureRefused::UntrustedKey(_))
        ));
        // Every field is covered: change any after signing and the signature fails.
        let tampered: [fn(&mut CheckpointMsg); 6] = [
            |m| m.weights[0] ^= 1,
            |m| m.epoch += 1,
            |m| m.validation_nll = -9.0,
            |m| m.config.push(' '),
            |m| m.task = "pouring".into(),
            |m| {
                m.kwargs.insert("obstacles".into(), 3.0.into());
            },
        ];
        for tamper in tampered {
            let mut changed = signed.clone();
            tamper(&mut changed);
            assert_eq!(trusted.verify(&changed), Err(SignatureRefused::Invalid));
        }
        // The attacker's key named as the signer of the trainer's signature: invalid.
        let mut swapped = signed.clone();
        if let (Some(s), Some(f)) = (&mut swapped.signature, &forged.signature) {
            s.key = f.key.clone();
        }
        assert!(trusted.verify(&swapped).is_err());
    }

    /// The throwaway test key pair made by `openssl genpkey -algorithm ed25519` and
    /// `openssl pkey -pubout` (`tests/keys`): the files users will bring.
    #[test]
    fn openssl_key_files_sign_and_verify() {
        const PRIVATE: &str = include_str!("../tests/keys/trainer.pem");
        const PUBLIC: &str = include_str!("../tests/keys/trainer.pub.pem");
        let dir = std::env::temp_dir().join(format!("ciflow-openssl-keys-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let (private, public) = (dir.join("trainer.pem"), dir.join("trainer.pub.pem"));
        std::fs::write(&private, PRIVATE).unwrap();
        std::fs::write(&public, PUBLIC).unwrap();
        let signer = CheckpointSigner::from_pem_file(&private).unwrap();
        let trusted = TrustedKeys::from_pem_files(std::slice::from_ref(&public)).unwrap();
        let mut signed = message();
        signer.sign(&mut signed);
        assert_eq!(trusted.verify(&signed), Ok(()));
        // The files swapped are clear errors, not a panic.
        assert!(matches!(
            CheckpointSigner::from_pem_file(&public),
            Err(KeyError::Private { .. })
        ));
        assert!(matches!(
            TrustedKeys::from_pem_files(&[private]),
            Err(KeyError::Public { .. })
        ));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
