//! impact server.
