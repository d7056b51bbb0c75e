//! Users and access control (`impact-server --users FILE`).
//!
//! A users file names each player's Zenoh user, password and client id. From it the server turns
//! on Zenoh's user/password authentication (a session that cannot prove a listed name is refused
//! before it sends a byte of data) and generates Zenoh access control with a default of deny, so
//! that each authenticated user may only:
//!
//! - put its own inputs, on `impact/v1/*/input/{client}`;
//! - declare its own presence token, on `impact/v1/*/presence/{client}`;
//! - subscribe to its own `impact/v1/*/client/{client}/**` and receive what is published there;
//! - subscribe to and receive the public streams ([`PUBLIC`]);
//! - query `impact/v1/*/query/state`, `.../query/history` and `.../query/scene` and receive the
//!   replies (the checkpoint query, every client's replay window, is for `[[server]]` peers).
//!
//! The world segment is `*`: a user is the same client in every world of the deployment, and one
//! set of rules serves a server with many worlds and a router in front of many servers.
//! `[[server]]` entries are other impact servers and routers of the same deployment: they may do
//! anything under `impact/v1/**`. In a router's configuration (`--print-acl`) they are the
//! servers behind it, which authenticate with the credentials of their own Zenoh configuration.
//!
//! Enforcement is on the session that accepts the connection. A server that connects out to a
//! router cannot also enforce: the router's link carries no user name, so a default-deny ACL
//! would cut it off. Such a server runs without `--users`, behind a router that enforces.
//!
//! Zenoh drops a denied message where it enters, silently: an impersonating put never reaches the
//! server, so it is not answered (there is nobody trustworthy to answer).

use super::error::RuntimeError;
use impact_protocol::keys::{self, KeyPattern};
use serde::Deserialize;
use serde_json::{json, Value};
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

/// The keys every user may subscribe to: they carry nothing private.
pub const PUBLIC: [KeyPattern; 4] = [keys::EVENTS, keys::CORRECTIONS, keys::CONFIRMED, keys::STATS];

/// One player: a Zenoh user name and password, and the client id it is.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct User {
    /// Zenoh user name.
    pub name: String,
    /// Its password.
    pub password: String,
    /// The client id this user acts as.
    pub client: u32,
    /// What it may do: play (the default) or run the game's logic.
    #[serde(default)]
    pub role: Role,
}

/// A user's role.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Role {
    /// A player: acts on the bodies it owns, hears what concerns it.
    #[default]
    Player,
    /// The game's logic: acts on any body (teleport, spawn, change class, push, remove), and
    /// hears every client's answers and events (the shots they fired, what hit them).
    Logic,
}

/// Another server or a router of the same deployment: trusted with every impact key.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Peer {
    /// Zenoh user name.
    pub name: String,
    /// Its password.
    pub password: String,
}

/// A parsed, checked users file.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Users {
    /// The players.
    #[serde(default, rename = "user")]
    pub users: Vec<User>,
    /// Servers and routers.
    #[serde(default, rename = "server")]
    pub servers: Vec<Peer>,
}

impl Users {
    /// Reads and checks a users file.
    pub fn load(path: &Path) -> Result<Users, RuntimeError> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| RuntimeError::Config(format!("reading users file {}: {e}", path.display())))?;
        Users::parse(&text).map_err(|e| RuntimeError::Config(format!("users file {}: {e}", path.display())))
    }

    /// Parses and checks a users file's text.
    pub fn parse(text: &str) -> Result<Users, String> {
        let users: Users = toml::from_str(text).map_err(|e| e.to_string())?;
        users.check()?;
        Ok(users)
    }

    /// Names unique and usable in Zenoh's dictionary, passwords non-empty, client ids unique.
    fn check(&self) -> Result<(), String> {
        if self.users.is_empty() {
            return Err("no [[user]] entries".into());
        }
        let mut names = BTreeSet::new();
        let mut clients = BTreeSet::new();
        let creds = self
            .users
            .iter()
            .map(|u| (&u.name, &u.password))
            .chain(self.servers.iter().map(|s| (&s.name, &s.password)));
        for (name, password) in creds {
            if name.is_empty()
                || name.len() > 128
                || !name.chars().all(|c| c.is_ascii_alphanumeric() || "-_.@".contains(c))
            {
                return Err(format!("user name {name:?}: 1 to 128 characters of A-Z a-z 0-9 - _ . @"));
            }
            if password.is_empty() || password.trim() != password || password.contains(['\n', '\r']) {
                return Err(format!(
                    "user {name:?}: the password must be non-empty, one line, without surrounding spaces"
                ));
            }
            if !names.insert(name.as_str()) {
                return Err(format!("user name {name:?} appears twice"));
            }
        }
        for u in &self.users {
            if !clients.insert(u.client) {
                return Err(format!("client {} belongs to two users", u.client));
            }
        }
        Ok(())
    }

    /// The clients of the users whose role is [`Role::Logic`].
    pub fn logic_clients(&self) -> impl Iterator<Item = impact_protocol::ClientId> + '_ {
        self.users.iter().filter(|u| u.role == Role::Logic).map(|u| impact_protocol::ClientId(u.client))
    }

    /// The user that is `client`, if any.
    pub fn for_client(&self, client: u32) -> Option<&User> {
        self.users.iter().find(|u| u.client == client)
    }

    /// Zenoh's user/password dictionary: one `name:password` line each.
    pub fn dictionary(&self) -> String {
        let users = self.users.iter().map(|u| (&u.name, &u.password));
        users.chain(self.servers.iter().map(|s| (&s.name, &s.password))).map(|(n, p)| format!("{n}:{p}\n")).collect()
    }

    /// The `access_control` section of a Zenoh configuration enforcing the rules above. Four
    /// rules (eight for game logic), a subject and a policy per user, plus seven shared rules (and
    /// two for `[[server]]`s).
    pub fn acl(&self) -> Value {
        let all = |p: KeyPattern| p.any_world();
        let own = |p: KeyPattern, c: u32| p.pattern.replace("{world}", "*").replace("{client}", &c.to_string());
        let client_tree = |c: u32| format!("impact/{}/*/client/{c}/**", keys::VERSION);
        let rule = |id: String, keys: Vec<String>, messages: &[&str], flow: &str| json!({"id": id, "key_exprs": keys, "messages": messages, "flows": [flow], "permission": "allow"});
        let public: Vec<String> = PUBLIC.iter().map(|p| all(*p)).collect();
        // The state, history and scene queries; the checkpoint (every seq window) is for servers.
        let queries: Vec<String> =
            [keys::QUERY_STATE, keys::QUERY_HISTORY, keys::QUERY_SCENE].iter().map(|p| all(*p)).collect();
        let everything = vec![format!("impact/{}/**", keys::VERSION)];
        let every_message = [
            "put",
            "delete",
            "declare_subscriber",
            "query",
            "declare_queryable",
            "reply",
            "liveliness_token",
            "declare_liveliness_subscriber",
            "liveliness_query",
        ];
        let mut rules = vec![
            rule("public-subscribe".into(), public.clone(), &["declare_subscriber"], "ingress"),
            rule("public-receive".into(), public, &["put"], "egress"),
            rule("query".into(), queries.clone(), &["query"], "ingress"),
            rule("query-reply".into(), queries.clone(), &["reply"], "egress"),
            // The server's own declarations must reach the clients, or their puts and queries
            // find no route: that the server subscribes to inputs and answers queries is public.
            rule("server-inputs".into(), vec![all(keys::INPUT)], &["declare_subscriber"], "egress"),
            rule("server-queries".into(), queries, &["declare_queryable"], "egress"),
            // That servers answer world commands is public too; only game logic may send one.
            rule("server-worlds".into(), vec![all(keys::WORLD_COMMAND)], &["declare_queryable"], "egress"),
            rule("peer-in".into(), everything.clone(), &every_message, "ingress"),
            rule("peer-out".into(), everything, &every_message, "egress"),
        ];
        let shared = [
            "public-subscribe",
            "public-receive",
            "query",
            "query-reply",
            "server-inputs",
            "server-queries",
            "server-worlds",
        ];
        let mut subjects = Vec::new();
        let mut policies = Vec::new();
        for u in &self.users {
            let c = u.client;
            let id = |what: &str| format!("client-{c}-{what}");
            rules.push(rule(id("input"), vec![own(keys::INPUT, c)], &["put"], "ingress"));
            rules.push(rule(id("presence"), vec![own(keys::PRESENCE, c)], &["liveliness_token"], "ingress"));
            rules.push(rule(id("subscribe"), vec![client_tree(c)], &["declare_subscriber"], "ingress"));
            rules.push(rule(id("receive"), vec![client_tree(c)], &["put"], "egress"));
            if u.role == Role::Logic {
                // Every client's tree: the answers to their shots, the events that involve them.
                let every = vec![format!("impact/{}/*/client/*/**", keys::VERSION)];
                rules.push(rule(id("logic-subscribe"), every.clone(), &["declare_subscriber"], "ingress"));
                rules.push(rule(id("logic-receive"), every, &["put"], "egress"));
                // Its own world commands (open and close a world), and their answers.
                let worlds = vec![own(keys::WORLD_COMMAND, c)];
                rules.push(rule(id("logic-worlds"), worlds.clone(), &["query"], "ingress"));
                rules.push(rule(id("logic-worlds-reply"), worlds, &["reply"], "egress"));
            }
            subjects.push(json!({"id": format!("user-{}", u.name), "usernames": [u.name]}));
            let mut own_rules: Vec<String> = ["input", "presence", "subscribe", "receive"].map(id).to_vec();
            if u.role == Role::Logic {
                own_rules.extend(["logic-subscribe", "logic-receive", "logic-worlds", "logic-worlds-reply"].map(id));
            }
            own_rules.extend(shared.iter().map(|s| s.to_string()));
            policies.push(json!({"rules": own_rules, "subjects": [format!("user-{}", u.name)]}));
        }
        if !self.servers.is_empty() {
            let names: Vec<&str> = self.servers.iter().map(|s| s.name.as_str()).collect();
            subjects.push(json!({"id": "servers", "usernames": names}));
            policies.push(json!({"rules": ["peer-in", "peer-out"], "subjects": ["servers"]}));
        } else {
            rules.retain(|r| !r["id"].as_str().is_some_and(|id| id.starts_with("peer-")));
        }
        json!({
            "enabled": true,
            "default_permission": "deny",
            "rules": rules,
            "subjects": subjects,
            "policies": policies,
        })
    }

    /// A Zenoh configuration fragment for a router in front of impact servers: the ACL above and
    /// the dictionary's path (the dictionary itself is [`Users::dictionary`], written beside it).
    pub fn router_config(&self, dictionary_path: &str) -> String {
        let cfg = json!({
            "transport": {"auth": {"usrpwd": {"dictionary_file": dictionary_path}}},
            "access_control": self.acl(),
        });
        serde_json::to_string_pretty(&cfg).unwrap_or_default()
    }

    /// Turns on authentication and the ACL in `config`, with the dictionary written to a file only
    /// this process's user can read (removed when the returned guard drops).
    pub fn apply(&self, config: &mut zenoh::Config) -> Result<Dictionary, RuntimeError> {
        // Endpoints are a list, or a list per mode: any string in there is an endpoint.
        fn any_endpoint(v: &Value) -> bool {
            match v {
                Value::String(_) => true,
                Value::Array(a) => a.iter().any(any_endpoint),
                Value::Object(o) => o.values().any(any_endpoint),
                _ => false,
            }
        }
        let connect = config.get_json("connect/endpoints").unwrap_or_default();
        if serde_json::from_str::<Value>(&connect).is_ok_and(|v| any_endpoint(&v)) {
            return Err(RuntimeError::Config(format!(
                "--users enforces access on the connections this server accepts, and would also cut off \
                 the router it connects to ({connect}: a router's link has no user name). Enforce at the \
                 router instead (`impact-server --users FILE --print-acl` prints its configuration) and run \
                 this server behind it without --users"
            )));
        }
        let dict = Dictionary::write(&self.dictionary())?;
        let err = |what: &str, e: zenoh::Error| RuntimeError::Config(format!("{what}: {e}"));
        let path = serde_json::to_string(&dict.path.to_string_lossy()).unwrap_or_default();
        config.insert_json5("transport/auth/usrpwd/dictionary_file", &path).map_err(|e| err("dictionary", e))?;
        config.insert_json5("access_control", &self.acl().to_string()).map_err(|e| err("access control", e))?;
        Ok(dict)
    }
}

/// The dictionary file Zenoh reads at session open; removed on drop.
#[derive(Debug)]
pub struct Dictionary {
    path: PathBuf,
}

impl Dictionary {
    fn write(text: &str) -> Result<Dictionary, RuntimeError> {
        use std::io::Write;
        use std::os::unix::fs::OpenOptionsExt;
        // The clock alone is not enough: two servers started at once in one process (tests do)
        // read the same nanosecond often enough to collide.
        static MADE: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
        let n = MADE.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_nanos());
        let path = std::env::temp_dir().join(format!("impact-users-{}-{nanos}-{n}.dict", std::process::id()));
        let mut f =
            std::fs::OpenOptions::new().write(true).create_new(true).mode(0o600).open(&path).map_err(|e| {
                RuntimeError::Config(format!("writing the password dictionary {}: {e}", path.display()))
            })?;
        f.write_all(text.as_bytes())
            .map_err(|e| RuntimeError::Config(format!("writing the password dictionary {}: {e}", path.display())))?;
        Ok(Dictionary { path })
    }
}

impl Drop for Dictionary {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}

/// Sets a client's credentials in its Zenoh configuration.
pub fn client_credentials(config: &mut zenoh::Config, user: &str, password: &str) -> Result<(), RuntimeError> {
    let q = |s: &str| serde_json::to_string(s).unwrap_or_default();
    let err = |e: zenoh::Error| RuntimeError::Config(format!("credentials: {e}"));
    config.insert_json5("transport/auth/usrpwd/user", &q(user)).map_err(err)?;
    config.insert_json5("transport/auth/usrpwd/password", &q(password)).map_err(err)
}

#[cfg(test)]
mod tests {
    use super::*;

    const FILE: &str = r#"
        [[user]]
        name = "alice"
        password = "correct horse"
        client = 1
        [[user]]
        name = "bob"
        password = "battery:staple"
        client = 2
    "#;

    #[test]
    fn users_file_is_checked() {
        let u = Users::parse(FILE).unwrap();
        assert_eq!(u.for_client(2).map(|u| u.name.as_str()), Some("bob"));
        assert_eq!(u.dictionary(), "alice:correct horse\nbob:battery:staple\n");
        let twice = FILE.replace("client = 2", "client = 1");
        assert!(Users::parse(&twice).unwrap_err().contains("client 1"));
        assert!(Users::parse(&FILE.replace("\"bob\"", "\"a:b\"")).is_err());
        assert!(Users::parse(&FILE.replace("\"battery:staple\"", "\"\"")).is_err());
        assert!(Users::parse(&FILE.replace("\"bob\"", "\"alice\"")).is_err());
        assert!(Users::parse("").is_err());
    }

    #[test]
    fn a_server_that_connects_out_cannot_enforce() {
        let u = Users::parse(FILE).unwrap();
        let mut c = zenoh::Config::default();
        c.insert_json5("connect/endpoints", r#"["tcp/127.0.0.1:7447"]"#).unwrap();
        let e = u.apply(&mut c).unwrap_err().to_string();
        assert!(e.contains("--print-acl"), "{e}");
    }

    #[test]
    fn the_generated_acl_is_a_valid_zenoh_configuration() {
        let u = Users::parse(&format!("{FILE}\n[[server]]\nname = \"edge\"\npassword = \"p\"\n")).unwrap();
        let mut c = zenoh::Config::default();
        let dict = u.apply(&mut c).expect("zenoh accepts the generated section");
        assert!(dict.path.exists());
        let acl = u.acl();
        assert_eq!(acl["default_permission"], "deny");
        assert_eq!(acl["rules"].as_array().unwrap().len(), 9 + 4 * 2);
        assert_eq!(acl["policies"].as_array().unwrap().len(), 3);
        let path = dict.path.clone();
        drop(dict);
        assert!(!path.exists(), "the dictionary is removed");
        let router: serde_json::Value = serde_json::from_str(&u.router_config("/etc/impact/users.dict")).unwrap();
        assert_eq!(router["access_control"], acl);
    }

    /// A `role = "logic"` user is a logic client, and its policy (alone) reaches every client's
    /// keys; zenoh accepts the configuration.
    #[test]
    fn a_logic_user_hears_every_client() {
        let text = format!("{FILE}\n[[user]]\nname = \"rules\"\npassword = \"p\"\nclient = 900\nrole = \"logic\"\n");
        let u = Users::parse(&text).unwrap();
        assert_eq!(u.logic_clients().collect::<Vec<_>>(), vec![impact_protocol::ClientId(900)]);
        let acl = u.acl();
        let every = format!("impact/{}/*/client/*/**", keys::VERSION);
        let rules = acl["rules"].as_array().unwrap();
        let reaching: Vec<&str> = rules
            .iter()
            .filter(|r| r["key_exprs"].as_array().unwrap().iter().any(|k| k == &every))
            .map(|r| r["id"].as_str().unwrap())
            .collect();
        assert_eq!(reaching, vec!["client-900-logic-subscribe", "client-900-logic-receive"]);
        let policies = acl["policies"].as_array().unwrap();
        let with =
            |id: &str| policies.iter().filter(|p| p["rules"].as_array().unwrap().iter().any(|r| r == id)).count();
        assert_eq!(with("client-900-logic-subscribe"), 1);
        let mut c = zenoh::Config::default();
        u.apply(&mut c).expect("zenoh accepts it");
        assert!(Users::parse(&text.replace("\"logic\"", "\"admin\"")).is_err(), "an unknown role is refused");
    }
}
