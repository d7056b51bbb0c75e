//! The users file (`impact-server --users FILE`, `impact-gateway --users FILE`): who may be
//! which client, and the access rules that follow from it.
//!
//! A users file names each player's Zenoh user, password and client id. From it a server (or a
//! router, `--print-acl`) turns on Zenoh's user/password authentication and generates Zenoh
//! access control with a default of deny ([`Users::acl`]), so that each authenticated user may only:
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
//! `[[gateway]]` entries are WebSocket gateways (`impact-gateway`): each may act for any player
//! (put any client's inputs, declare any client's presence, hear any client's keys), because it
//! checks each browser player's own credentials itself and relays only that player's keys.
//!
//! This module is the file's model, shared by the server and the gateway; turning it into a
//! Zenoh configuration is the server's (`impact_server::runtime::auth`).

use crate::keys::{self, KeyPattern};
use serde::Deserialize;
use serde_json::{json, Value};
use std::collections::BTreeSet;

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

/// Another server or a router of the same deployment (trusted with every impact key), or a
/// gateway (trusted to act for any player).
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
    /// WebSocket gateways: each relays many players, checking their credentials itself.
    #[serde(default, rename = "gateway")]
    pub gateways: Vec<Peer>,
}

impl Users {
    /// Parses and checks a users file's text.
    pub fn parse(text: &str) -> Result<Users, String> {
        let users: Users = toml::from_str(text).map_err(|e| e.to_string())?;
        users.check()?;
        Ok(users)
    }

    /// Names unique and usable in Zenoh's dictionary, passwords non-empty, client ids unique.
    fn check(&self) -> Result<(), String> {
        if self.users.is_empty() && self.gateways.is_empty() {
            return Err("no [[user]] or [[gateway]] entries".into());
        }
        let mut names = BTreeSet::new();
        let mut clients = BTreeSet::new();
        let creds =
            self.users.iter().map(|u| (&u.name, &u.password)).chain(self.peers().map(|s| (&s.name, &s.password)));
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
    pub fn logic_clients(&self) -> impl Iterator<Item = crate::ClientId> + '_ {
        self.users.iter().filter(|u| u.role == Role::Logic).map(|u| crate::ClientId(u.client))
    }

    /// The user that is `client`, if any.
    pub fn for_client(&self, client: u32) -> Option<&User> {
        self.users.iter().find(|u| u.client == client)
    }

    /// Zenoh's user/password dictionary: one `name:password` line each.
    pub fn dictionary(&self) -> String {
        let users = self.users.iter().map(|u| (&u.name, &u.password));
        users.chain(self.peers().map(|s| (&s.name, &s.password))).map(|(n, p)| format!("{n}:{p}\n")).collect()
    }

    /// The servers, routers and gateways.
    fn peers(&self) -> impl Iterator<Item = &Peer> + '_ {
        self.servers.iter().chain(&self.gateways)
    }

    /// The gateway entry named `name`, if any.
    pub fn gateway(&self, name: &str) -> Option<&Peer> {
        self.gateways.iter().find(|g| g.name == name)
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
        // The state, history, confirmed and scene queries; the checkpoint (every seq window) is
        // for servers.
        let queries: Vec<String> = [keys::QUERY_STATE, keys::QUERY_HISTORY, keys::QUERY_CONFIRMED, keys::QUERY_SCENE]
            .iter()
            .map(|p| all(*p))
            .collect();
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
        // Every protocol version's server tokens: a client of another version learns so.
        let servers = keys::SERVER.pattern.replace("{world}", "*").replacen(keys::VERSION, "*", 1);
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
            // Finding a world's server (and its protocol version) before joining: a liveliness
            // query on the servers' tokens, answered with them.
            rule("find-server".into(), vec![servers.clone()], &["liveliness_query"], "ingress"),
            rule("server-tokens".into(), vec![servers], &["liveliness_token", "reply"], "egress"),
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
            "find-server",
            "server-tokens",
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
        if !self.gateways.is_empty() {
            let any = |p: KeyPattern| p.pattern.replace("{world}", "*").replace("{client}", "*");
            let every = vec![format!("impact/{}/*/client/*/**", keys::VERSION)];
            rules.push(rule("gateway-input".into(), vec![any(keys::INPUT)], &["put"], "ingress"));
            rules.push(rule("gateway-presence".into(), vec![any(keys::PRESENCE)], &["liveliness_token"], "ingress"));
            rules.push(rule("gateway-subscribe".into(), every.clone(), &["declare_subscriber"], "ingress"));
            rules.push(rule("gateway-receive".into(), every, &["put"], "egress"));
            let names: Vec<&str> = self.gateways.iter().map(|g| g.name.as_str()).collect();
            subjects.push(json!({"id": "gateways", "usernames": names}));
            let mut own: Vec<String> = ["gateway-input", "gateway-presence", "gateway-subscribe", "gateway-receive"]
                .map(String::from)
                .to_vec();
            own.extend(shared.iter().map(|s| s.to_string()));
            policies.push(json!({"rules": own, "subjects": ["gateways"]}));
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

    /// The rules each policy names, by the policy's subject.
    fn policy_rules(acl: &Value, subject: &str) -> Vec<String> {
        let policies = acl["policies"].as_array().unwrap();
        let p = policies.iter().find(|p| p["subjects"][0] == subject).unwrap();
        p["rules"].as_array().unwrap().iter().map(|r| r.as_str().unwrap().to_string()).collect()
    }

    /// A `role = "logic"` user is a logic client, and its policy (alone) reaches every client's
    /// keys.
    #[test]
    fn a_logic_user_hears_every_client() {
        let text = format!("{FILE}\n[[user]]\nname = \"rules\"\npassword = \"p\"\nclient = 900\nrole = \"logic\"\n");
        let u = Users::parse(&text).unwrap();
        assert_eq!(u.logic_clients().collect::<Vec<_>>(), vec![crate::ClientId(900)]);
        let acl = u.acl();
        let every = format!("impact/{}/*/client/*/**", keys::VERSION);
        let rules = acl["rules"].as_array().unwrap();
        let reaching: Vec<&str> = rules
            .iter()
            .filter(|r| r["key_exprs"].as_array().unwrap().iter().any(|k| k == &every))
            .map(|r| r["id"].as_str().unwrap())
            .collect();
        assert_eq!(reaching, vec!["client-900-logic-subscribe", "client-900-logic-receive"]);
        assert!(policy_rules(&acl, "user-rules").contains(&"client-900-logic-subscribe".to_string()));
        assert!(!policy_rules(&acl, "user-alice").contains(&"client-900-logic-subscribe".to_string()));
        assert!(Users::parse(&text.replace("\"logic\"", "\"admin\"")).is_err(), "an unknown role is refused");
    }

    /// A gateway may act for any player, and only a gateway: a file of gateways alone is valid
    /// (its players bring tokens), and the players' policies do not reach other clients.
    #[test]
    fn a_gateway_acts_for_any_player() {
        let only = Users::parse("[[gateway]]\nname = \"edge-ws\"\npassword = \"p\"\n").unwrap();
        assert_eq!(only.gateway("edge-ws").map(|g| g.password.as_str()), Some("p"));
        assert_eq!(only.dictionary(), "edge-ws:p\n");
        let u = Users::parse(&format!("{FILE}\n[[gateway]]\nname = \"edge-ws\"\npassword = \"p\"\n")).unwrap();
        let acl = u.acl();
        let gw = policy_rules(&acl, "gateways");
        for r in ["gateway-input", "gateway-presence", "gateway-subscribe", "gateway-receive", "query"] {
            assert!(gw.contains(&r.to_string()), "{r} in {gw:?}");
        }
        let input = acl["rules"].as_array().unwrap().iter().find(|r| r["id"] == "gateway-input").unwrap();
        assert_eq!(input["key_exprs"][0], format!("impact/{}/*/input/*", keys::VERSION));
        assert!(policy_rules(&acl, "user-alice").iter().all(|r| !r.starts_with("gateway-")));
        assert!(Users::parse(&format!("{FILE}\n[[gateway]]\nname = \"alice\"\npassword = \"p\"\n")).is_err());
    }
}
