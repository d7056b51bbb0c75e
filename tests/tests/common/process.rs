//! Real processes for end-to-end tests (see `impact_client_sim::process`).

pub use impact_client_sim::process::*;

/// `target/<profile>/impact-server` of this build.
pub fn server_binary() -> std::path::PathBuf {
    binary("impact-server")
}
