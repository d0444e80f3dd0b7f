//! Signed checkpoints: an engine that trusts a key hot-loads only what that key signed —
//! unsigned, foreign-signed and altered publications are refused while the trainer's keep
//! loading — and an engine that trusts no key (the default) loads them all.

mod common;

use std::path::Path;
use std::time::{Duration, Instant};

use ciflow_bridge::protocol::{CheckpointMsg, encode, keys};
use ciflow_bridge::{
    CheckpointPolicy, CheckpointPublisher, CheckpointSigner, Client, EngineServer, NetworkOptions,
    Policy, Role, ServerOptions, TaskFactory, TrustedKeys,
};
use common::*;
use ed25519_dalek::pkcs8::spki::der::pem::LineEnding;
use ed25519_dalek::pkcs8::{EncodePrivateKey, EncodePublicKey};
use zenoh::Wait;

/// The epoch `engine` serves policy `avoid` at.
fn served_epoch(client: &Client, engine: &str) -> Option<u64> {
    let info = client.engine_info(engine).unwrap();
    info.policies
        .iter()
        .find(|p| p.name == "avoid")
        .unwrap()
        .epoch
}

/// Waits until `engine` serves epoch `epoch` of `avoid`; whether it did within 5 s.
fn serves(client: &Client, engine: &str, epoch: u64) -> bool {
    eventually(5.0, || served_epoch(client, engine) == Some(epoch))
}

/// A key pair written as PEM files, as `openssl genpkey`/`openssl pkey -pubout` would.
fn write_key(dir: &Path, name: &str, seed: u8) -> (std::path::PathBuf, std::path::PathBuf) {
    let key = ed25519_dalek::SigningKey::from_bytes(&[seed; 32]);
    let (private, public) = (
        dir.join(format!("{name}.pem")),
        dir.join(format!("{name}.pub.pem")),
    );
    std::fs::write(
        &private,
        key.to_pkcs8_pem(LineEnding::LF).unwrap().as_bytes(),
    )
    .unwrap();
    let pem = key
        .verifying_key()
        .to_public_key_pem(LineEnding::LF)
        .unwrap();
    std::fs::write(&public, pem).unwrap();
    (private, public)
}

#[test]
fn an_engine_that_trusts_a_key_loads_only_what_it_signed() {
    let dir = write_checkpoint("signing");
    let (trainer_key, trainer_public) = write_key(&dir, "trainer", 3);
    let (attacker_key, _) = write_key(&dir, "attacker", 4);
    let port = 27451;
    let tasks = TaskFactory::registry();
    let policy = || -> std::sync::Arc<dyn Policy> {
        std::sync::Arc::new(
            CheckpointPolicy::load(Some("avoid"), &dir, &tasks, &one_obstacle()).unwrap(),
        )
    };
    let guarded = EngineServer::open(
        &NetworkOptions::endpoint(Role::Engine, &endpoint(port)),
        ServerOptions {
            name: Some("guarded".into()),
            policies: vec![policy()],
            trusted_keys: Some(TrustedKeys::from_pem_files(&[trainer_public]).unwrap()),
            ..ServerOptions::default()
        },
    )
    .unwrap();
    // The control: an engine on the same Zenoh session that trusts no key.
    let open = EngineServer::start(
        guarded.zenoh_session().clone(),
        ServerOptions {
            name: Some("open".into()),
            policies: vec![policy()],
            ..ServerOptions::default()
        },
    )
    .unwrap();
    // Two policies under one name: refused, not one silently replacing the other.
    let twice = EngineServer::start(
        guarded.zenoh_session().clone(),
        ServerOptions {
            name: Some("twice".into()),
            policies: vec![policy(), policy()],
            ..ServerOptions::default()
        },
    );
    assert!(
        matches!(&twice, Err(error) if error.to_string().contains("two policies are named `avoid`")),
        "{:?}",
        twice.err()
    );
    let client = connect(port);
    let network = NetworkOptions::endpoint(Role::Client, &endpoint(port));
    let publisher = |signer: Option<CheckpointSigner>| {
        CheckpointPublisher::open(&network, "avoid")
            .unwrap()
            .with_kwargs(one_obstacle())
            .with_signer(signer)
    };
    let trainer = publisher(Some(CheckpointSigner::from_pem_file(&trainer_key).unwrap()));
    let unsigned = publisher(None);
    let attacker = publisher(Some(
        CheckpointSigner::from_pem_file(&attacker_key).unwrap(),
    ));
    // The engines' subscriptions must have reached the publishers' sessions first.
    std::thread::sleep(Duration::from_millis(300));

    trainer.publish(&dir, 1, -1.0).unwrap();
    assert!(
        serves(&client, "guarded", 1),
        "the trainer's checkpoint loads"
    );
    assert!(serves(&client, "open", 1));

    unsigned.publish(&dir, 2, -2.0).unwrap();
    assert!(
        serves(&client, "open", 2),
        "the control loads an unsigned checkpoint"
    );
    attacker.publish(&dir, 3, -3.0).unwrap();
    assert!(
        serves(&client, "open", 3),
        "the control loads a foreign-signed one"
    );
    // A checkpoint the trainer signed, altered afterwards.
    let zsession = client.zenoh_session();
    let samples = zsession
        .declare_subscriber(keys::policy_checkpoint("avoid"))
        .wait()
        .unwrap();
    std::thread::sleep(Duration::from_millis(300));
    trainer.publish(&dir, 4, -4.0).unwrap();
    assert!(serves(&client, "guarded", 4));
    let deadline = Instant::now() + Duration::from_secs(5);
    let signed: CheckpointMsg = loop {
        let sample = samples.recv_timeout(Duration::from_millis(100)).unwrap();
        if let Some(sample) = sample {
            break rmp_serde::from_slice(&sample.payload().to_bytes()).unwrap();
        }
        assert!(
            Instant::now() < deadline,
            "the trainer's publication arrives"
        );
    };
    assert!(signed.signature.is_some());
    let altered = CheckpointMsg { epoch: 5, ..signed };
    let key = keys::policy_checkpoint("avoid");
    zsession.put(&key, encode(&altered)).wait().unwrap();
    assert!(
        serves(&client, "open", 5),
        "the control loads the altered one"
    );
    assert_eq!(
        served_epoch(&client, "guarded"),
        Some(4),
        "the guarded engine did not"
    );
    // The trainer's next one still loads.
    trainer.publish(&dir, 6, -6.0).unwrap();
    assert!(serves(&client, "guarded", 6));
    drop((open, guarded));
    std::fs::remove_dir_all(&dir).unwrap();
}
