//! Generated types and gRPC stubs for `proto/mo_env/v1/env.proto`.
#![allow(missing_docs, unreachable_pub, clippy::all, reason = "generated code")]

/// Version 1 of the protocol.
pub mod v1 {
    tonic::include_proto!("mo_env.v1");
}
