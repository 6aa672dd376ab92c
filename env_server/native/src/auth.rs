//! Bearer tokens, checked here rather than in Python so that a Step's check costs no
//! GIL time. `env_server/security.py` loads the token file and defines the contract;
//! the messages below are its MISSING_TOKEN, MALFORMED_TOKEN and UNKNOWN_TOKEN, word
//! for word (the Python tests compare both fronts' answers to those constants).

use subtle::ConstantTimeEq;
use tonic::Status;
use tonic::metadata::MetadataMap;

const MISSING_TOKEN: &str =
    "expected metadata 'authorization: Bearer <token>', got no authorization metadata";
const MALFORMED_TOKEN: &str = "expected metadata 'authorization: Bearer <token>', got a value that does not start with 'Bearer '";
const UNKNOWN_TOKEN: &str =
    "the bearer token in 'authorization' matches none of this server's tokens (--auth-token-file)";

/// The tokens a server accepts, each with the client name it stands for.
pub(crate) struct Tokens {
    entries: Vec<(String, Vec<u8>)>,
}

impl Tokens {
    /// `(name, token)` pairs as `security.Tokens.entries` holds them.
    pub(crate) fn new(entries: Vec<(String, String)>) -> Self {
        Self {
            entries: entries
                .into_iter()
                .map(|(name, token)| (name, token.into_bytes()))
                .collect(),
        }
    }

    /// The client name of the call's `authorization` metadata, or UNAUTHENTICATED.
    /// Every token is compared, each in constant time, so the time taken does not say
    /// which token (or how much of one) matched.
    fn identify(&self, metadata: &MetadataMap) -> Result<String, Status> {
        let value = metadata
            .get("authorization")
            .ok_or_else(|| Status::unauthenticated(MISSING_TOKEN))?
            .as_bytes();
        let prefix = b"bearer ";
        if value.len() < prefix.len() || !value[..prefix.len()].eq_ignore_ascii_case(prefix) {
            return Err(Status::unauthenticated(MALFORMED_TOKEN));
        }
        let offered = value[prefix.len()..].trim_ascii();
        let mut found = None;
        for (name, token) in &self.entries {
            if bool::from(offered.ct_eq(token)) {
                found = Some(name);
            }
        }
        found
            .cloned()
            .ok_or_else(|| Status::unauthenticated(UNKNOWN_TOKEN))
    }
}

/// The caller's client name under `tokens`; None when the server takes no tokens.
pub(crate) fn owner(
    tokens: Option<&Tokens>,
    metadata: &MetadataMap,
) -> Result<Option<String>, Status> {
    tokens.map(|t| t.identify(metadata)).transpose()
}
