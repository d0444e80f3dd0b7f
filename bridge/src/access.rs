//! Who may do what on a ciflow network, as the access-control rules of a Zenoh router.
//!
//! Zenoh's access control runs on the router every process connects to. It sees each
//! message's kind, its key expression and the authenticated name of the peer it comes
//! from or goes to (here: the common name of the peer's TLS client certificate), never
//! the payload. The protocol's key layout (see `keys`) puts everything that needs
//! guarding in the key, so these rules are enough:
//!
//! | role | may | so that |
//! |---|---|---|
//! | engine `E` | serve and reply under `…/engine/E/`, publish its telemetry and frames there, hold `alive/engine/E` | nobody else can receive clients' requests or answer them |
//! | client `C` | query and subscribe under `…/engine/*/client/C/`, ask any engine's `tasks`, `ping` and `act`, hold `alive/client/C/*`, publish episodes as recorder `C` | nobody drives, closes or watches another identity's sessions, or claims its name |
//! | trainer `T` | publish on `policies/*/checkpoint`, subscribe to episodes | only named trainers publish policies |
//!
//! Everything else is denied (`default_permission: deny`). A rule allows a message when
//! one of its key expressions *includes* the message's, and a message crossing the router
//! is checked twice: on the way in, against its sender's rules (`ingress`), and on the way
//! out, against its receiver's (`egress`). So a role also needs, on egress, what the
//! others send it: queries and subscriptions to an engine, replies and publications to a
//! client, and the declarations with which Zenoh tells queriers and publishers that
//! anyone answers or listens (a client's querier without them sends nothing).

use serde::Serialize;

use crate::error::{BridgeError, check_name};
use crate::protocol::keys::ROOT;

/// The names of the processes a router lets take part, by role; each is the common name
/// of that process's certificate, and for engines and clients also the name it uses in
/// keys (`ciflow serve --name E`, `--identity C`).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct AccessPolicy {
    /// An engine allowed to serve under its name (repeatable).
    #[cfg_attr(feature = "clap", arg(long = "engine", value_name = "NAME"))]
    pub engines: Vec<String>,
    /// A trainer allowed to publish checkpoints (repeatable).
    #[cfg_attr(feature = "clap", arg(long = "trainer", value_name = "NAME"))]
    pub trainers: Vec<String>,
    /// A client identity allowed to make and drive sessions of its own (repeatable).
    #[cfg_attr(feature = "clap", arg(long = "client", value_name = "NAME"))]
    pub clients: Vec<String>,
}

impl AccessPolicy {
    /// Whether any name is given (with none, a router enforces nothing).
    pub fn is_empty(&self) -> bool {
        self.engines.is_empty() && self.trainers.is_empty() && self.clients.is_empty()
    }

    /// The `access_control` section of a Zenoh configuration enforcing this policy, as
    /// JSON (valid JSON5). Names must be single key chunks.
    pub fn to_json(&self) -> Result<String, BridgeError> {
        let mut config = AccessControl {
            enabled: true,
            default_permission: "deny",
            rules: Vec::new(),
            subjects: Vec::new(),
            policies: Vec::new(),
        };
        for (role, names, grants) in [
            (
                "engine",
                &self.engines,
                engine_grants as fn(&str) -> Vec<Grant>,
            ),
            ("trainer", &self.trainers, trainer_grants),
            ("client", &self.clients, client_grants),
        ] {
            for name in names {
                check_name(&format!("{role} name"), name)?;
                config.grant(&format!("{role}-{name}"), name, grants(name));
            }
        }
        serde_json::to_string_pretty(&config)
            .map_err(|e| BridgeError::InvalidArgument(format!("cannot write the rules: {e}")))
    }
}

/// Who the policy lets in, for logs: `open to every peer` when it names nobody.
impl std::fmt::Display for AccessPolicy {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.is_empty() {
            return write!(f, "open to every peer");
        }
        write!(
            f,
            "access control on: engines [{}], trainers [{}], clients [{}]",
            self.engines.join(", "),
            self.trainers.join(", "),
            self.clients.join(", ")
        )
    }
}

/// What one subject may do on one flow: `messages` on keys included in `keys`.
struct Grant {
    flow: &'static str,
    messages: &'static [&'static str],
    keys: Vec<String>,
}

fn grant(flow: &'static str, messages: &'static [&'static str], keys: &[&str]) -> Grant {
    Grant {
        flow,
        messages,
        keys: keys.iter().map(|k| format!("{ROOT}/{k}")).collect(),
    }
}

const IN: &str = "ingress";
const OUT: &str = "egress";

fn engine_grants(engine: &str) -> Vec<Grant> {
    let own = format!("engine/{engine}/**");
    let token = format!("alive/engine/{engine}");
    vec![
        grant(IN, &["declare_queryable", "put", "delete"], &[&own]),
        // Replies carry the query's key, which names any engine (`*`) when the client did.
        grant(IN, &["reply"], &["engine/**"]),
        grant(IN, &["liveliness_token"], &[&token]),
        grant(IN, &["declare_subscriber"], &["policies/*/checkpoint"]),
        grant(
            IN,
            &["declare_liveliness_subscriber", "liveliness_query"],
            &["alive/client/*/*"],
        ),
        // Queries and telemetry subscriptions reach an engine only through the queryable
        // and publisher it declared, which are confined to its own keys above.
        grant(OUT, &["query", "declare_subscriber"], &["engine/**"]),
        grant(OUT, &["put"], &["policies/*/checkpoint"]),
        grant(OUT, &["liveliness_token", "reply"], &["alive/client/*/*"]),
    ]
}

fn client_grants(client: &str) -> Vec<Grant> {
    let own = format!("engine/*/client/{client}/**");
    let public: [&str; 3] = ["engine/*/tasks", "engine/*/ping", "engine/*/policy/*/act"];
    let token = format!("alive/client/{client}/*");
    let episodes = format!("episodes/*/{client}");
    vec![
        grant(IN, &["query", "declare_subscriber"], &[&own]),
        grant(IN, &["query"], &public),
        grant(IN, &["liveliness_token"], &[&token]),
        grant(
            IN,
            &["declare_liveliness_subscriber", "liveliness_query"],
            &["alive/engine/*"],
        ),
        grant(IN, &["put"], &[&episodes]),
        grant(OUT, &["reply", "put"], &[&own]),
        grant(OUT, &["reply"], &public),
        grant(OUT, &["liveliness_token", "reply"], &["alive/engine/*"]),
        // Declarations tell a client's queriers and publishers that someone answers or
        // listens (without them they send nothing); they carry no data.
        grant(OUT, &["declare_queryable"], &["engine/**"]),
        grant(OUT, &["declare_subscriber"], &["episodes/**"]),
    ]
}

fn trainer_grants(_trainer: &str) -> Vec<Grant> {
    vec![
        grant(IN, &["put"], &["policies/*/checkpoint"]),
        grant(IN, &["declare_subscriber"], &["episodes/**"]),
        grant(
            IN,
            &["declare_liveliness_subscriber", "liveliness_query"],
            &["alive/engine/*"],
        ),
        grant(OUT, &["declare_subscriber"], &["policies/*/checkpoint"]),
        grant(OUT, &["put"], &["episodes/**"]),
        grant(OUT, &["liveliness_token", "reply"], &["alive/engine/*"]),
    ]
}

/// Zenoh's `access_control` section (zenoh-config's `AclConfig`).
#[derive(Serialize)]
struct AccessControl {
    enabled: bool,
    default_permission: &'static str,
    rules: Vec<Rule>,
    subjects: Vec<Subject>,
    policies: Vec<PolicyEntry>,
}

#[derive(Serialize)]
struct Rule {
    id: String,
    messages: &'static [&'static str],
    flows: [&'static str; 1],
    permission: &'static str,
    key_exprs: Vec<String>,
}

#[derive(Serialize)]
struct Subject {
    id: String,
    cert_common_names: [String; 1],
}

#[derive(Serialize)]
struct PolicyEntry {
    rules: Vec<String>,
    subjects: [String; 1],
}

impl AccessControl {
    /// Lets the peer whose certificate names `common_name` do what `grants` say.
    fn grant(&mut self, subject: &str, common_name: &str, grants: Vec<Grant>) {
        let mut rule_ids = Vec::new();
        for (i, grant) in grants.into_iter().enumerate() {
            let id = format!("{subject}-{i}");
            rule_ids.push(id.clone());
            self.rules.push(Rule {
                id,
                messages: grant.messages,
                flows: [grant.flow],
                permission: "allow",
                key_exprs: grant.keys,
            });
        }
        self.subjects.push(Subject {
            id: subject.to_owned(),
            cert_common_names: [common_name.to_owned()],
        });
        self.policies.push(PolicyEntry {
            rules: rule_ids,
            subjects: [subject.to_owned()],
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn policy() -> AccessPolicy {
        AccessPolicy {
            engines: vec!["engine-1".into()],
            trainers: vec!["trainer-1".into()],
            clients: vec!["alice".into(), "bob".into()],
        }
    }

    #[test]
    fn zenoh_accepts_the_rules_it_is_given() {
        let mut config = zenoh::Config::default();
        config
            .insert_json5("access_control", &policy().to_json().unwrap())
            .expect("a valid access_control section");
        let back = config.get_json("access_control/subjects").unwrap();
        for name in ["engine-1", "trainer-1", "alice", "bob"] {
            assert!(back.contains(&format!("\"{name}\"")), "{name} in {back}");
        }
    }

    #[test]
    fn a_client_is_confined_to_its_own_prefix() {
        let json: serde_json::Value = serde_json::from_str(&policy().to_json().unwrap()).unwrap();
        let keys_of = |subject: &str, flow: &str, message: &str| -> Vec<String> {
            json["rules"]
                .as_array()
                .unwrap()
                .iter()
                .filter(|r| {
                    r["id"]
                        .as_str()
                        .unwrap()
                        .starts_with(&format!("{subject}-"))
                })
                .filter(|r| r["flows"][0] == flow)
                .filter(|r| {
                    r["messages"]
                        .as_array()
                        .unwrap()
                        .iter()
                        .any(|m| m == message)
                })
                .flat_map(|r| r["key_exprs"].as_array().unwrap().clone())
                .map(|k| k.as_str().unwrap().to_owned())
                .collect()
        };
        let alice_queries = keys_of("client-alice", "ingress", "query");
        assert!(alice_queries.contains(&"ciflow/v2/engine/*/client/alice/**".to_owned()));
        assert!(alice_queries.iter().all(|k| !k.contains("bob")));
        assert!(keys_of("client-alice", "ingress", "declare_queryable").is_empty());
        assert!(keys_of("client-alice", "ingress", "reply").is_empty());
        assert_eq!(
            keys_of("client-alice", "ingress", "liveliness_token"),
            ["ciflow/v2/alive/client/alice/*"]
        );
        assert!(
            keys_of("client-alice", "ingress", "put")
                .iter()
                .all(|k| !k.contains("policies"))
        );
        assert_eq!(
            keys_of("trainer-trainer-1", "ingress", "put"),
            ["ciflow/v2/policies/*/checkpoint"]
        );
        assert_eq!(
            keys_of("engine-engine-1", "ingress", "declare_queryable"),
            ["ciflow/v2/engine/engine-1/**"]
        );
    }

    #[test]
    fn names_that_are_not_key_chunks_are_refused() {
        for bad in ["", "a/b", "*", "al ice"] {
            let policy = AccessPolicy {
                clients: vec![bad.into()],
                ..AccessPolicy::default()
            };
            assert!(policy.to_json().is_err(), "{bad:?}");
        }
        assert!(AccessPolicy::default().is_empty());
        assert!(!policy().is_empty());
    }
}
