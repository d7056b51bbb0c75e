//! Signed, expiring player tokens: how a game backend lets a browser player in without a users
//! file entry of its own.
//!
//! The backend and the gateway share a secret (`impact-gateway --token-secret FILE`, at least 32
//! bytes). The backend, having logged the player in its own way, issues
//!
//! ```text
//! v1.{client}.{world}.{expires}.{signature}
//! ```
//!
//! where `expires` is a Unix time in seconds and `signature` the lowercase hex HMAC-SHA256 of
//! everything before the last dot, keyed with the secret. The player's hello carries it; the
//! gateway checks the signature (in constant time) and the expiry, and relays that player as
//! `client` in `world`, nothing else. `impact-gateway token` issues one from the command line;
//! PROTOCOL.md ("WebSocket binding") shows the same in a few lines of Python.

use hmac::{Hmac, Mac};
use impact_protocol::{ClientId, WorldId};
use sha2::Sha256;

/// The shortest secret accepted, in bytes.
pub const MIN_SECRET_BYTES: usize = 32;
/// The longest token read, in bytes (a longer one is refused before any work).
pub const MAX_TOKEN_BYTES: usize = 256;

/// Why a token was refused.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum TokenError {
    /// Not `v1.{client}.{world}.{expires}.{signature}`.
    #[error("the token is not v1.CLIENT.WORLD.EXPIRES.SIGNATURE")]
    Malformed,
    /// The signature does not match: not issued with this gateway's secret, or altered.
    #[error("the token's signature does not match")]
    Signature,
    /// Past its expiry.
    #[error("the token expired at {expires} (now {now}, Unix seconds)")]
    Expired {
        /// When it expired.
        expires: u64,
        /// The gateway's clock.
        now: u64,
    },
}

/// What a valid token lets its bearer be.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Grant {
    /// The client id.
    pub client: ClientId,
    /// The world.
    pub world: WorldId,
    /// Unix seconds after which the token is refused (a connection made before goes on).
    pub expires: u64,
}

/// The shared secret, checked for length.
#[derive(Clone)]
pub struct Secret(Vec<u8>);

impl std::fmt::Debug for Secret {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Secret({} bytes)", self.0.len())
    }
}

impl Secret {
    /// A secret of at least [`MIN_SECRET_BYTES`] bytes (a file's contents, surrounding
    /// whitespace removed).
    pub fn new(bytes: &[u8]) -> Result<Secret, String> {
        let trimmed = bytes.trim_ascii();
        if trimmed.len() < MIN_SECRET_BYTES {
            return Err(format!(
                "the token secret has {} bytes, at least {MIN_SECRET_BYTES} are needed (e.g. `head -c 32 /dev/urandom | base64`)",
                trimmed.len()
            ));
        }
        Ok(Secret(trimmed.to_vec()))
    }

    /// A fresh random secret (the operating system's randomness): for guest tokens when no
    /// secret is shared with a backend. Gone when the gateway stops, with the tokens it signed.
    pub fn random() -> std::io::Result<Secret> {
        let mut bytes = [0u8; MIN_SECRET_BYTES];
        getrandom::fill(&mut bytes).map_err(|e| std::io::Error::other(format!("no randomness for a secret: {e}")))?;
        Ok(Secret(bytes.to_vec()))
    }

    fn mac(&self) -> Hmac<Sha256> {
        // HMAC takes a key of any length.
        Hmac::<Sha256>::new_from_slice(&self.0).unwrap_or_else(|_| unreachable!("HMAC accepts any key length"))
    }

    /// The token for `grant`.
    pub fn issue(&self, grant: &Grant) -> String {
        let body = format!("v1.{}.{}.{}", grant.client.0, grant.world.as_str(), grant.expires);
        let mut mac = self.mac();
        mac.update(body.as_bytes());
        let sig: String = mac.finalize().into_bytes().iter().map(|b| format!("{b:02x}")).collect();
        format!("{body}.{sig}")
    }

    /// Checks `token` at `now` (Unix seconds): the grant it carries, or why not.
    pub fn verify(&self, token: &str, now: u64) -> Result<Grant, TokenError> {
        if token.len() > MAX_TOKEN_BYTES {
            return Err(TokenError::Malformed);
        }
        let (body, sig) = token.rsplit_once('.').ok_or(TokenError::Malformed)?;
        let sig = hex(sig).ok_or(TokenError::Malformed)?;
        let mut mac = self.mac();
        mac.update(body.as_bytes());
        mac.verify_slice(&sig).map_err(|_| TokenError::Signature)?;
        // Signed by us: the fields are as issued, but parse them as carefully as any input.
        let mut parts = body.split('.');
        let (Some("v1"), Some(client), Some(world), Some(expires), None) =
            (parts.next(), parts.next(), parts.next(), parts.next(), parts.next())
        else {
            return Err(TokenError::Malformed);
        };
        let client = client.parse().map(ClientId).map_err(|_| TokenError::Malformed)?;
        let world = WorldId::new(world).map_err(|_| TokenError::Malformed)?;
        let expires: u64 = expires.parse().map_err(|_| TokenError::Malformed)?;
        if now > expires {
            return Err(TokenError::Expired { expires, now });
        }
        Ok(Grant { client, world, expires })
    }
}

/// Lowercase or uppercase hex to bytes.
fn hex(s: &str) -> Option<Vec<u8>> {
    if s.len() % 2 != 0 {
        return None;
    }
    (0..s.len()).step_by(2).map(|i| u8::from_str_radix(s.get(i..i + 2)?, 16).ok()).collect()
}

/// The time now in Unix seconds (0 if the clock is before 1970).
pub fn unix_now() -> u64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_secs())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn secret() -> Secret {
        Secret::new(b"0123456789abcdef0123456789abcdef\n").unwrap()
    }

    fn grant() -> Grant {
        Grant { client: ClientId(7), world: WorldId::new("arena").unwrap(), expires: 2_000_000_000 }
    }

    #[test]
    fn a_token_carries_its_grant_until_it_expires() {
        let t = secret().issue(&grant());
        assert!(t.starts_with("v1.7.arena.2000000000."), "{t}");
        assert_eq!(secret().verify(&t, 1_999_999_999), Ok(grant()));
        assert_eq!(secret().verify(&t, 2_000_000_000), Ok(grant()), "valid through its last second");
        assert_eq!(
            secret().verify(&t, 2_000_000_001),
            Err(TokenError::Expired { expires: 2_000_000_000, now: 2_000_000_001 })
        );
    }

    /// Any change to the body, or another secret, breaks the signature.
    #[test]
    fn a_changed_token_is_refused() {
        let t = secret().issue(&grant());
        for forged in
            [t.replace("v1.7.", "v1.8."), t.replace(".arena.", ".other."), t.replace(".2000000000.", ".2100000000.")]
        {
            assert_eq!(secret().verify(&forged, 0), Err(TokenError::Signature), "{forged}");
        }
        let other = Secret::new(b"another secret of at least 32 bytes").unwrap();
        assert_eq!(other.verify(&t, 0), Err(TokenError::Signature));
        let mut flipped = t.clone();
        let last = if flipped.ends_with('0') { '1' } else { '0' };
        flipped.pop();
        flipped.push(last);
        assert_eq!(secret().verify(&flipped, 0), Err(TokenError::Signature));
    }

    #[test]
    fn garbage_is_malformed_and_short_secrets_refused() {
        for bad in ["", "v1", "v1.7.arena.1", "v1.7.arena.1.zz", "v1.7.arena.1.abc", &"a".repeat(MAX_TOKEN_BYTES + 1)] {
            assert_eq!(secret().verify(bad, 0), Err(TokenError::Malformed), "{bad:?}");
        }
        // Well signed but not the format: refused all the same.
        let s = secret();
        let mut mac = s.mac();
        mac.update(b"v2.7.arena.1");
        let sig: String = mac.finalize().into_bytes().iter().map(|b| format!("{b:02x}")).collect();
        assert_eq!(s.verify(&format!("v2.7.arena.1.{sig}"), 0), Err(TokenError::Malformed));
        assert!(Secret::new(b"short").unwrap_err().contains("at least 32"));
    }
}
