//! Generates the EnvService server trait for this front with `codec::RequestCodec`, so a
//! request that does not decode is the client's INVALID_ARGUMENT (tonic's ProstCodec
//! makes it INTERNAL). Only the server is generated here: the messages are mo-env-proto's
//! (extern_path), and the agent's client keeps tonic's codec.
fn main() -> Result<(), Box<dyn std::error::Error>> {
    let protoc = protoc_bin_vendored::protoc_bin_path()?;
    // SAFETY: build scripts are single-threaded; prost-build reads PROTOC from the environment.
    unsafe { std::env::set_var("PROTOC", protoc) };
    println!("cargo:rerun-if-changed=../../proto/mo_env/v1/env.proto");
    tonic_prost_build::configure()
        .build_server(true)
        .build_client(false)
        .extern_path(".mo_env.v1", "::mo_env_proto::v1")
        .codec_path("crate::codec::RequestCodec")
        .compile_protos(&["../../proto/mo_env/v1/env.proto"], &["../../proto"])?;
    Ok(())
}
