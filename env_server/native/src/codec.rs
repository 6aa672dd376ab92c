//! The native front's gRPC codec: prost, except that request bytes that do not decode
//! (not a protobuf message, invalid UTF-8 in a string field, ...) are the client's
//! INVALID_ARGUMENT naming the method and the message type, as on the grpc.aio front.
//! tonic's `ProstCodec` makes them INTERNAL, which tells a client the server is broken.

use std::marker::PhantomData;

use bytes::Buf;
use prost::Message;
use tonic::codec::{Codec, DecodeBuf, Decoder};
use tonic::{Code, Status};
use tonic_prost::ProstEncoder;

/// The codec build.rs names for every EnvService method (`Encode` = response, `Decode` = request).
#[derive(Debug)]
pub(crate) struct RequestCodec<T, U>(PhantomData<(T, U)>);

impl<T, U> Default for RequestCodec<T, U> {
    fn default() -> Self {
        Self(PhantomData)
    }
}

impl<T, U> Codec for RequestCodec<T, U>
where
    T: Message + Send + 'static,
    U: Message + Default + Send + 'static,
{
    type Encode = T;
    type Decode = U;
    type Encoder = ProstEncoder<T>;
    type Decoder = RequestDecoder<U>;

    fn encoder(&mut self) -> Self::Encoder {
        ProstEncoder::default()
    }

    fn decoder(&mut self) -> Self::Decoder {
        RequestDecoder(PhantomData)
    }
}

/// Decodes one request message `U`.
#[derive(Debug)]
pub(crate) struct RequestDecoder<U>(PhantomData<U>);

impl<U: Message + Default> Decoder for RequestDecoder<U> {
    type Item = U;
    type Error = Status;

    fn decode(&mut self, buf: &mut DecodeBuf<'_>) -> Result<Option<U>, Status> {
        let len = buf.remaining();
        U::decode(buf).map(Some).map_err(|err| {
            // The codec is not told the method; every request type but StepRequest has
            // one (`MakeRequest` -> Make), and StepStream renames its own (`in_stream`).
            let short = std::any::type_name::<U>().rsplit("::").next().unwrap_or("?");
            let method = short.strip_suffix("Request").unwrap_or(short);
            Status::invalid_argument(format!(
                "{method}: expected a serialized mo_env.v1.{short}, got {len} bytes that do not parse as one ({err})"
            ))
        })
    }
}

/// A StepStream request's decode error, which the codec named after Step.
pub(crate) fn in_stream(status: Status) -> Status {
    match status.message().strip_prefix("Step: ") {
        Some(rest) if status.code() == Code::InvalidArgument => {
            Status::invalid_argument(format!("StepStream: {rest}"))
        }
        _ => status,
    }
}
