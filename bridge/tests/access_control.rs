//! The example secure deployment (`deploy/secure`: QUIC/TLS with client certificates, every
//! process a Zenoh client of one router that enforces `AccessPolicy`) under attack by an
//! insider: `mallory` holds a valid certificate and a client identity of her own. Each
//! attack of the outside tester's report is tried while `alice` keeps stepping, and each
//! is refused; the legitimate flows (alice's sessions and telemetry, the trainer's signed
//! checkpoints) keep working. The negative control runs the first attacks on the default
//! open network, where they succeed.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::thread::JoinHandle;
use std::time::Duration;

use ciflow_bridge::protocol::{
    ErrorCode, MakeRequest, PROTOCOL_VERSION, SessionRequest, encode, keys,
};
use ciflow_bridge::{
    AccessPolicy, BridgeError, CheckpointPolicy, CheckpointPublisher, CheckpointSigner, Client,
    EngineServer, NetworkOptions, Policy, RemoteEnv, Role, Router, ServerOptions, TaskFactory,
    TrustedKeys, query_all,
};
use common::*;
use zenoh::Wait;
use zenoh::query::Query;

const ENGINE: &str = "engine-1";
const TRAINER: &str = "trainer-1";

/// Certificates and Zenoh configurations made by the deployment's own script.
fn make_certificates(port: u16, names: &[&str]) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("ciflow-secure-{port}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/secure/make-certs.sh");
    let status = Command::new("bash")
        .arg(&script)
        .arg(&dir)
        .args(names)
        .env("ROUTER_ENDPOINT", format!("quic/localhost:{port}"))
        .env("ROUTER_LISTEN", format!("quic/127.0.0.1:{port}"))
        .status()
        .expect("run deploy/secure/make-certs.sh (needs bash and openssl)");
    assert!(status.success(), "make-certs.sh failed");
    dir
}

/// How `name` joins: its Zenoh configuration from the script, under its own identity.
fn joining_as(dir: &Path, name: &str) -> NetworkOptions {
    NetworkOptions {
        config_file: Some(dir.join(format!("{name}.json5"))),
        identity: Some(name.to_owned()),
        ..NetworkOptions::default()
    }
}

/// An engine named [`ENGINE`] serving the fixture and policy `avoid` (a checkpoint at
/// `policy_dir`), hot-loading only what `trusted` signed.
fn start_engine_as(network: &NetworkOptions, policy_dir: &Path, trusted: &Path) -> EngineServer {
    let tasks = TaskFactory::registry();
    let policy = CheckpointPolicy::load(Some("avoid"), policy_dir, &tasks, &one_obstacle())
        .expect("load the policy");
    let mut options = ServerOptions {
        name: Some(ENGINE.into()),
        policies: vec![Arc::new(policy) as Arc<dyn Policy>],
        trusted_keys: Some(TrustedKeys::from_pem_files(&[trusted.to_path_buf()]).unwrap()),
        ..ServerOptions::default()
    };
    options.tasks.push(fixture_task());
    EngineServer::open(network, options).expect("the engine joins")
}

/// A session of the fixture stepped without pause on its own thread until `stop`;
/// counts steps and failures.
struct Stepper {
    steps: Arc<AtomicU64>,
    failures: Arc<AtomicU64>,
    stop: Arc<AtomicBool>,
    thread: JoinHandle<()>,
}

impl Stepper {
    fn start(env: Arc<RemoteEnv>) -> Self {
        let steps = Arc::new(AtomicU64::new(0));
        let failures = Arc::new(AtomicU64::new(0));
        let stop = Arc::new(AtomicBool::new(false));
        let (s, f, done) = (Arc::clone(&steps), Arc::clone(&failures), Arc::clone(&stop));
        let thread = std::thread::spawn(move || {
            env.reset(Some(1), None).unwrap();
            while !done.load(Ordering::Relaxed) {
                match env.step(&[0.1]) {
                    Ok(step) => {
                        s.fetch_add(1, Ordering::Relaxed);
                        if step.truncated || step.terminated {
                            env.reset(None, None).unwrap();
                        }
                    }
                    Err(error) => {
                        eprintln!("alice's step failed: {error}");
                        f.fetch_add(1, Ordering::Relaxed);
                    }
                }
            }
        });
        Self {
            steps,
            failures,
            stop,
            thread,
        }
    }

    fn steps(&self) -> u64 {
        self.steps.load(Ordering::Relaxed)
    }

    /// Stops stepping; the number of steps and of failed steps.
    fn finish(self) -> (u64, u64) {
        self.stop.store(true, Ordering::Relaxed);
        self.thread.join().unwrap();
        (
            self.steps.load(Ordering::Relaxed),
            self.failures.load(Ordering::Relaxed),
        )
    }
}

/// The payloads a sniffing queryable heard.
type Heard = Arc<std::sync::Mutex<Vec<Vec<u8>>>>;

/// A queryable of `zsession` on `key` that keeps the payload of every query it receives
/// (and answers nothing).
fn sniff(zsession: &zenoh::Session, key: &str) -> (zenoh::query::Queryable<()>, Heard) {
    let heard = Arc::new(std::sync::Mutex::new(Vec::new()));
    let sink = Arc::clone(&heard);
    let queryable = zsession
        .declare_queryable(key)
        .callback(move |query: Query| {
            let payload = query.payload().map(|p| p.to_bytes().into_owned());
            sink.lock().unwrap().push(payload.unwrap_or_default());
        })
        .wait()
        .unwrap();
    (queryable, heard)
}

/// The payloads of `key`'s replies; denied queries have none.
fn replies(zsession: &zenoh::Session, key: &str, payload: Vec<u8>) -> Vec<Vec<u8>> {
    query_all(zsession, key, payload, Duration::from_secs(2))
        .unwrap()
        .into_iter()
        .map(|reply| reply.unwrap_or_else(|error| encode(&error)))
        .collect()
}

/// A `make` of one fixture environment owned by `owner`'s process.
fn make_for(owner: &Client) -> Vec<u8> {
    encode(&MakeRequest {
        v: PROTOCOL_VERSION,
        instance: owner.instance().to_owned(),
        task: FIXTURE_ID.into(),
        num_envs: 1,
        kwargs: no_kwargs(),
        deadline_ms: None,
    })
}

fn close_request(token: &[u8]) -> Vec<u8> {
    encode(&SessionRequest {
        v: PROTOCOL_VERSION,
        token: serde_bytes::ByteBuf::from(token.to_vec()),
        index: 0,
    })
}

#[test]
fn behind_the_secure_router_every_attack_is_refused_while_alice_keeps_stepping() {
    let port = 27461;
    let dir = make_certificates(port, &[ENGINE, TRAINER, "alice", "mallory"]);
    let policy = AccessPolicy {
        engines: vec![ENGINE.into()],
        trainers: vec![TRAINER.into()],
        clients: vec!["alice".into(), "mallory".into()],
    };
    let router_config = NetworkOptions {
        config_file: Some(dir.join("router.json5")),
        ..NetworkOptions::default()
    };
    let _router = Router::open(&router_config, &policy).expect("the router starts");

    let keys_dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/keys");
    let policy_dir = write_checkpoint("secure");
    let engine = start_engine_as(
        &joining_as(&dir, ENGINE),
        &policy_dir,
        &keys_dir.join("trainer.pub.pem"),
    );
    let alice = Client::open(&joining_as(&dir, "alice")).expect("alice joins");
    let mallory = Client::open(&joining_as(&dir, "mallory")).expect("mallory joins");
    let zm = mallory.zenoh_session();

    // The legitimate flows pass the router: alice makes, steps and watches her session.
    let env = Arc::new(alice.make(ENGINE, FIXTURE_ID, 1, &no_kwargs()).unwrap());
    let telemetry = env.control().telemetry().unwrap();
    let stepper = Stepper::start(Arc::clone(&env));
    assert!(eventually(5.0, || stepper.steps() > 20), "alice steps");
    assert!(
        telemetry
            .recv_timeout(Duration::from_secs(5))
            .unwrap()
            .is_some(),
        "alice sees her telemetry"
    );

    // 1. A queryable on the engine's keys or on alice's hears nothing, so it cannot read
    //    tokens or answer (spoof) anything; and a subscriber sees none of her telemetry.
    let (_q1, heard_engine) = sniff(zm, &format!("{}/**", keys::engine(ENGINE)));
    let (_q2, heard_alice) = sniff(zm, "ciflow/v2/engine/*/client/alice/**");
    let peeked = zm
        .declare_subscriber("ciflow/v2/engine/*/client/mallory/**")
        .wait()
        .unwrap();
    std::thread::sleep(Duration::from_millis(500));
    let before = stepper.steps();
    let second = alice
        .make(ENGINE, FIXTURE_ID, 1, &no_kwargs())
        .expect("alice's make gets the engine's own reply");
    second.reset(Some(2), None).unwrap();
    assert!(eventually(5.0, || stepper.steps() > before + 50));
    assert_eq!(
        heard_engine.lock().unwrap().len(),
        0,
        "sniffed on the engine's keys"
    );
    assert_eq!(
        heard_alice.lock().unwrap().len(),
        0,
        "sniffed on alice's keys"
    );
    assert!(
        peeked.try_recv().unwrap().is_none(),
        "mallory read alice's telemetry"
    );

    // 2. Closing alice's session, even with her token (had it leaked): under her identity
    //    the router drops the query; under mallory's the engine knows no such session.
    let foreign = keys::session(ENGINE, "alice", env.session_id(), "close");
    assert!(replies(zm, &foreign, close_request(env.token())).is_empty());
    let under_mallory = mallory
        .attach(ENGINE, env.session_id(), env.token())
        .unwrap();
    assert!(matches!(
        under_mallory.stop(),
        Err(BridgeError::Remote(reply)) if reply.code == ErrorCode::UnknownSession
    ));

    // 3. Owning a session as alice: a `make` under her identity is dropped; one naming her
    //    process under mallory's identity finds no such process of mallory's; a token in
    //    alice's name never reaches the engine.
    let as_alice = make_for(&alice);
    assert!(replies(zm, &keys::make(ENGINE, "alice"), as_alice.clone()).is_empty());
    let error = raw_query(zm, &keys::make(ENGINE, "mallory"), as_alice).unwrap_err();
    assert_eq!(error.code, ErrorCode::NoLiveliness);
    let _forged = zm
        .liveliness()
        .declare_token(keys::client_alive("alice/forged"))
        .wait()
        .unwrap();
    std::thread::sleep(Duration::from_millis(300));
    let alive: Vec<String> = engine
        .zenoh_session()
        .liveliness()
        .get("ciflow/v2/alive/client/alice/*")
        .timeout(Duration::from_secs(2))
        .wait()
        .unwrap()
        .iter()
        .filter_map(|reply| reply.into_result().ok())
        .map(|sample| sample.key_expr().to_string())
        .collect();
    assert_eq!(alive, [keys::client_alive(alice.id())]);

    // 4. Checkpoints: the trainer's signed one loads; mallory's, unsigned or signed with
    //    her own key, never reach the engine.
    let trainer = CheckpointPublisher::open(&joining_as(&dir, TRAINER), "avoid")
        .unwrap()
        .with_kwargs(one_obstacle())
        .with_signer(Some(
            CheckpointSigner::from_pem_file(&keys_dir.join("trainer.pem")).unwrap(),
        ));
    let rogue = |signer| {
        CheckpointPublisher::open(&joining_as(&dir, "mallory"), "avoid")
            .unwrap()
            .with_kwargs(one_obstacle())
            .with_signer(signer)
    };
    let served = |epoch| {
        eventually(5.0, || {
            alice.engine_info(ENGINE).unwrap().policies[0].epoch == Some(epoch)
        })
    };
    std::thread::sleep(Duration::from_millis(300));
    trainer.publish(&policy_dir, 1, -1.0).unwrap();
    assert!(
        served(1),
        "the trainer's checkpoint loads through the router"
    );
    rogue(None).publish(&policy_dir, 7, -7.0).unwrap();
    let attacker_key = policy_dir.join("mallory.pem");
    std::fs::copy(keys_dir.join("trainer.pem"), &attacker_key).unwrap();
    // Even the trainer's own key in mallory's hands: the router drops her publications.
    rogue(Some(
        CheckpointSigner::from_pem_file(&attacker_key).unwrap(),
    ))
    .publish(&policy_dir, 8, -8.0)
    .unwrap();
    std::thread::sleep(Duration::from_secs(1));
    assert!(served(1), "a rogue checkpoint was loaded");

    // 5. Without a certificate of the deployment's CA nobody joins.
    let anonymous = NetworkOptions::endpoint(Role::Client, &format!("tcp/127.0.0.1:{port}"));
    assert!(Client::open(&anonymous).is_err(), "joined over plain TCP");
    let no_certificate = dir.join("no-certificate.json5");
    std::fs::write(
        &no_certificate,
        format!(
            r#"{{ mode: "client", connect: {{ endpoints: ["quic/localhost:{port}"] }},
                 scouting: {{ multicast: {{ enabled: false }} }},
                 transport: {{ link: {{ tls: {{ root_ca_certificate: "{}" }} }} }} }}"#,
            dir.join("ca.pem").display()
        ),
    )
    .unwrap();
    let without = NetworkOptions {
        config_file: Some(no_certificate),
        ..NetworkOptions::default()
    };
    assert!(
        Client::open(&without).is_err(),
        "joined without a certificate"
    );

    // Mallory is a client in her own right, and alice never missed a step.
    let hers = mallory.make(ENGINE, FIXTURE_ID, 1, &no_kwargs()).unwrap();
    hers.reset(Some(3), None).unwrap();
    let (steps, failures) = stepper.finish();
    assert_eq!(failures, 0, "alice's steps failed during the attacks");
    assert!(steps > 100, "alice stepped {steps} times");
    env.step(&[0.0]).expect("alice's session is intact");
    let _ = std::fs::remove_dir_all(&dir);
    let _ = std::fs::remove_dir_all(&policy_dir);
}

/// The negative control: on the default open network (no router, no certificates) the
/// same insider hears alice's requests, takes her token from them, closes her session
/// and makes one in her name.
#[test]
fn on_the_open_network_the_same_attacks_succeed() {
    let port = 27462;
    let engine = start_engine(port);
    let joining = |identity: &str| NetworkOptions {
        identity: Some(identity.into()),
        ..NetworkOptions::endpoint(Role::Client, &endpoint(port))
    };
    let alice = Client::open(&joining("alice")).unwrap();
    let mallory = Client::open(&joining("mallory")).unwrap();
    let zm = mallory.zenoh_session();
    let (_sniffer, heard) = sniff(zm, "ciflow/v2/engine/*/client/alice/**");
    std::thread::sleep(Duration::from_millis(300));

    let env = alice
        .make(engine.name(), FIXTURE_ID, 1, &no_kwargs())
        .unwrap();
    env.reset(Some(1), None).unwrap();
    assert!(
        eventually(5.0, || heard.lock().unwrap().len() >= 2),
        "the sniffer hears alice's requests"
    );
    #[derive(serde::Deserialize)]
    struct WithToken {
        token: serde_bytes::ByteBuf,
    }
    let stolen: WithToken = heard
        .lock()
        .unwrap()
        .iter()
        .find_map(|payload| rmp_serde::from_slice(payload).ok())
        .expect("a request with alice's token");
    let foreign = keys::session(engine.name(), "alice", env.session_id(), "close");
    let closed = replies(zm, &foreign, close_request(&stolen.token));
    assert_eq!(closed.len(), 1);
    assert!(env.step(&[0.0]).is_err(), "alice's session survived");

    let in_her_name = make_for(&alice);
    assert!(raw_query(zm, &keys::make(engine.name(), "alice"), in_her_name).is_ok());
}
