//! Who a browser player is: its hello checked against the users file or a signed token.
//!
//! The trust model (PROTOCOL.md, "WebSocket binding"): the gateway holds one Zenoh credential,
//! a `[[gateway]]` entry of the users file, whose access rules let it act for any player. It
//! earns that trust by checking every player itself, here, and by relaying each connection only
//! on the keys of the client it authenticated (`crate::relay`): a browser never names a key, so
//! it cannot publish as another player or read another's stream. One session for all its
//! players, rather than one per player: a Zenoh session costs threads and memory, and hundreds
//! of them would make the gateway the bottleneck it is there to remove.

use crate::token::{Secret, TokenError};
use crate::wire::Hello;
use impact_protocol::users::Users;
use impact_protocol::{ClientId, WorldId};

/// A player the gateway relays: the client and world its credentials allow.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Player {
    /// Its client id.
    pub client: ClientId,
    /// Its world.
    pub world: WorldId,
}

/// Why a hello was refused. The text reaches the browser in the close frame: it says what to
/// fix without saying which of a user name and a password was wrong.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum AuthError {
    /// Neither a user with a password nor a token.
    #[error("send user and password, or token")]
    NoCredentials,
    /// A user and password but no `world` or `client`.
    #[error("a hello with user and password names its world and client")]
    Incomplete,
    /// The world name is not one.
    #[error("world {0:?} is not a world name")]
    BadWorld(String),
    /// This gateway takes no passwords (no users file).
    #[error("this gateway takes tokens, not passwords")]
    NoPasswords,
    /// This gateway takes no tokens (no secret).
    #[error("this gateway takes user and password, not tokens")]
    NoTokens,
    /// Unknown user or wrong password.
    #[error("user or password wrong")]
    Password,
    /// The user is another client.
    #[error("user is not client {0}")]
    NotThisClient(u32),
    /// The token was refused.
    #[error("{0}")]
    Token(#[from] TokenError),
    /// The token is for another client or world than the hello asks.
    #[error("the token is for client {client} in {world}")]
    NotTheTokens {
        /// The token's client.
        client: u32,
        /// The token's world.
        world: String,
    },
}

/// What the gateway accepts.
#[derive(Clone, Debug, Default)]
pub struct Authenticator {
    /// Players' users and passwords (`--users`).
    pub users: Option<Users>,
    /// The token secret (`--token-secret`).
    pub secret: Option<Secret>,
}

impl Authenticator {
    /// The player `hello` proves to be at `now` (Unix seconds), or why not.
    pub fn check(&self, hello: &Hello, now: u64) -> Result<Player, AuthError> {
        match (&hello.token, &hello.user, &hello.password) {
            (Some(token), _, _) => self.by_token(hello, token, now),
            (None, Some(user), Some(password)) => self.by_password(hello, user, password),
            _ => Err(AuthError::NoCredentials),
        }
    }

    fn by_token(&self, hello: &Hello, token: &str, now: u64) -> Result<Player, AuthError> {
        let secret = self.secret.as_ref().ok_or(AuthError::NoTokens)?;
        let grant = secret.verify(token, now)?;
        let other_client = hello.client.is_some_and(|c| c != grant.client.0);
        let other_world = hello.world.as_deref().is_some_and(|w| w != grant.world.as_str());
        if other_client || other_world {
            return Err(AuthError::NotTheTokens { client: grant.client.0, world: grant.world.as_str().to_string() });
        }
        Ok(Player { client: grant.client, world: grant.world })
    }

    fn by_password(&self, hello: &Hello, user: &str, password: &str) -> Result<Player, AuthError> {
        let users = self.users.as_ref().ok_or(AuthError::NoPasswords)?;
        let (Some(world), Some(client)) = (&hello.world, hello.client) else { return Err(AuthError::Incomplete) };
        let world = WorldId::new(world.as_str()).map_err(|_| AuthError::BadWorld(world.chars().take(64).collect()))?;
        // The same work whether the user exists or not, so the time taken does not say.
        let known = users.users.iter().find(|u| u.name == user);
        let expected = known.map_or("", |u| u.password.as_str());
        let matches = same(expected.as_bytes(), password.as_bytes());
        let Some(u) = known.filter(|_| matches) else { return Err(AuthError::Password) };
        if u.client != client {
            return Err(AuthError::NotThisClient(client));
        }
        Ok(Player { client: ClientId(client), world })
    }
}

/// Compares two secrets in time that depends on their lengths only.
fn same(a: &[u8], b: &[u8]) -> bool {
    let longest = a.len().max(b.len());
    let mut diff = u8::from(a.len() != b.len());
    for i in 0..longest {
        diff |= a.get(i).copied().unwrap_or(0) ^ b.get(i).copied().unwrap_or(0);
    }
    diff == 0
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::token::Grant;

    const USERS: &str = r#"
        [[user]]
        name = "alice"
        password = "correct horse"
        client = 1
        [[gateway]]
        name = "edge-ws"
        password = "g"
    "#;

    fn hello(
        world: Option<&str>,
        client: Option<u32>,
        user: Option<&str>,
        password: Option<&str>,
        token: Option<&str>,
    ) -> Hello {
        Hello {
            world: world.map(String::from),
            client,
            user: user.map(String::from),
            password: password.map(String::from),
            token: token.map(String::from),
            state: None,
        }
    }

    fn both() -> Authenticator {
        Authenticator { users: Some(Users::parse(USERS).unwrap()), secret: Some(Secret::new(&[b'k'; 32]).unwrap()) }
    }

    #[test]
    fn a_password_proves_its_users_client_only() {
        let a = both();
        let alice = Player { client: ClientId(1), world: WorldId::new("arena").unwrap() };
        assert_eq!(a.check(&hello(Some("arena"), Some(1), Some("alice"), Some("correct horse"), None), 0), Ok(alice));
        let wrong = hello(Some("arena"), Some(1), Some("alice"), Some("correct horsE"), None);
        assert_eq!(a.check(&wrong, 0), Err(AuthError::Password));
        let nobody = hello(Some("arena"), Some(1), Some("mallory"), Some("correct horse"), None);
        assert_eq!(a.check(&nobody, 0), Err(AuthError::Password), "the same answer as a wrong password");
        let as_bob = hello(Some("arena"), Some(2), Some("alice"), Some("correct horse"), None);
        assert_eq!(a.check(&as_bob, 0), Err(AuthError::NotThisClient(2)));
        // The gateway's own credential is not a player's.
        let gw = hello(Some("arena"), Some(1), Some("edge-ws"), Some("g"), None);
        assert_eq!(a.check(&gw, 0), Err(AuthError::Password));
        assert_eq!(
            a.check(&hello(None, Some(1), Some("alice"), Some("correct horse"), None), 0),
            Err(AuthError::Incomplete)
        );
        let bad_world = hello(Some("Arena!"), Some(1), Some("alice"), Some("correct horse"), None);
        assert!(matches!(a.check(&bad_world, 0), Err(AuthError::BadWorld(_))));
        assert_eq!(a.check(&hello(Some("arena"), Some(1), None, None, None), 0), Err(AuthError::NoCredentials));
    }

    #[test]
    fn a_token_proves_its_grant_only() {
        let a = both();
        let world = WorldId::new("arena").unwrap();
        let t = a.secret.as_ref().unwrap().issue(&Grant { client: ClientId(9), world: world.clone(), expires: 100 });
        assert_eq!(a.check(&hello(None, None, None, None, Some(&t)), 50), Ok(Player { client: ClientId(9), world }));
        assert_eq!(
            a.check(&hello(Some("arena"), Some(9), None, None, Some(&t)), 50).map(|p| p.client),
            Ok(ClientId(9))
        );
        assert!(matches!(
            a.check(&hello(None, Some(1), None, None, Some(&t)), 50),
            Err(AuthError::NotTheTokens { .. })
        ));
        assert!(matches!(
            a.check(&hello(Some("lobby"), None, None, None, Some(&t)), 50),
            Err(AuthError::NotTheTokens { .. })
        ));
        assert!(matches!(
            a.check(&hello(None, None, None, None, Some(&t)), 101),
            Err(AuthError::Token(TokenError::Expired { .. }))
        ));
        let no_tokens = Authenticator { secret: None, ..both() };
        assert_eq!(no_tokens.check(&hello(None, None, None, None, Some(&t)), 50), Err(AuthError::NoTokens));
        let no_users = Authenticator { users: None, ..both() };
        let pw = hello(Some("arena"), Some(1), Some("alice"), Some("correct horse"), None);
        assert_eq!(no_users.check(&pw, 0), Err(AuthError::NoPasswords));
    }

    #[test]
    fn comparison_is_exact() {
        assert!(same(b"abc", b"abc") && same(b"", b""));
        assert!(!same(b"abc", b"abd") && !same(b"abc", b"ab") && !same(b"ab", b"abc"));
        assert!(!same(b"", b"\0") && !same(b"\0", b""), "a zero byte is not an absent one");
    }
}
