//! Users and access control (`impact-server --users FILE`): the users file
//! ([`impact_protocol::users`], which says what each user may do) turned into a Zenoh
//! configuration.
//!
//! Enforcement is on the session that accepts the connection. A server that connects out to a
//! router cannot also enforce: the router's link carries no user name, so a default-deny ACL
//! would cut it off. Such a server runs without `--users`, behind a router that enforces.
//!
//! Zenoh drops a denied message where it enters, silently: an impersonating put never reaches the
//! server, so it is not answered (there is nobody trustworthy to answer).

use super::error::RuntimeError;
pub use impact_protocol::users::{Peer, Role, User, Users, PUBLIC};
use serde_json::Value;
use std::path::{Path, PathBuf};

/// Reads and checks a users file.
pub fn load(path: &Path) -> Result<Users, RuntimeError> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| RuntimeError::Config(format!("reading users file {}: {e}", path.display())))?;
    Users::parse(&text).map_err(|e| RuntimeError::Config(format!("users file {}: {e}", path.display())))
}

/// Turns on authentication and the ACL in `config`, with the dictionary written to a file only
/// this process's user can read (removed when the returned guard drops).
pub fn apply(users: &Users, config: &mut zenoh::Config) -> Result<Dictionary, RuntimeError> {
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
    let dict = Dictionary::write(&users.dictionary())?;
    let err = |what: &str, e: zenoh::Error| RuntimeError::Config(format!("{what}: {e}"));
    let path = serde_json::to_string(&dict.path.to_string_lossy()).unwrap_or_default();
    config.insert_json5("transport/auth/usrpwd/dictionary_file", &path).map_err(|e| err("dictionary", e))?;
    config.insert_json5("access_control", &users.acl().to_string()).map_err(|e| err("access control", e))?;
    Ok(dict)
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
        name = "rules"
        password = "p"
        client = 900
        role = "logic"
        [[gateway]]
        name = "edge-ws"
        password = "p"
    "#;

    #[test]
    fn a_server_that_connects_out_cannot_enforce() {
        let u = Users::parse(FILE).unwrap();
        let mut c = zenoh::Config::default();
        c.insert_json5("connect/endpoints", r#"["tcp/127.0.0.1:7447"]"#).unwrap();
        let e = apply(&u, &mut c).unwrap_err().to_string();
        assert!(e.contains("--print-acl"), "{e}");
    }

    /// Players, game logic, a gateway and a server: Zenoh accepts the generated section.
    #[test]
    fn the_generated_acl_is_a_valid_zenoh_configuration() {
        let u = Users::parse(&format!("{FILE}\n[[server]]\nname = \"edge\"\npassword = \"p\"\n")).unwrap();
        let mut c = zenoh::Config::default();
        let dict = apply(&u, &mut c).expect("zenoh accepts the generated section");
        assert!(dict.path.exists());
        let acl = u.acl();
        assert_eq!(acl["default_permission"], "deny");
        // 11 shared, 4 a player, 4 more for logic, 4 for the gateways.
        assert_eq!(acl["rules"].as_array().unwrap().len(), 11 + 4 * 2 + 4 + 4);
        assert_eq!(acl["policies"].as_array().unwrap().len(), 4);
        let path = dict.path.clone();
        drop(dict);
        assert!(!path.exists(), "the dictionary is removed");
        let router: serde_json::Value = serde_json::from_str(&u.router_config("/etc/impact/users.dict")).unwrap();
        assert_eq!(router["access_control"], acl);
    }
}
