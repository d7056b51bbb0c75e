//! The runtime's one error type: what can stop a server from starting or running.

/// Why the server could not start or run.
#[derive(Debug, thiserror::Error)]
pub enum RuntimeError {
    /// The Zenoh configuration is invalid.
    #[error("zenoh configuration: {0}")]
    Config(String),
    /// Zenoh refused a session or a declaration.
    #[error("zenoh: {0}")]
    Zenoh(String),
    /// A thread could not be started.
    #[error("thread: {0}")]
    Thread(String),
}
