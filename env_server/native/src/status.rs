//! Statuses: Python's code names to tonic codes, Python exceptions to statuses (through
//! the service's own `status_of`, so both fronts report the same thing), and tonic's
//! oversized-message error to the RESOURCE_EXHAUSTED that docs/env-server.md ("The protocol") (and grpc core,
//! which the grpc.aio front uses) gives it.

use http::Response;
use pyo3::prelude::*;
use tonic::{Code, Status};

/// The status for `code_name` (a `grpc.StatusCode` name such as "INVALID_ARGUMENT").
pub(crate) fn from_code_name(code_name: &str, message: &str) -> Status {
    let code = match code_name {
        "OK" => Code::Ok,
        "CANCELLED" => Code::Cancelled,
        "UNKNOWN" => Code::Unknown,
        "INVALID_ARGUMENT" => Code::InvalidArgument,
        "DEADLINE_EXCEEDED" => Code::DeadlineExceeded,
        "NOT_FOUND" => Code::NotFound,
        "ALREADY_EXISTS" => Code::AlreadyExists,
        "PERMISSION_DENIED" => Code::PermissionDenied,
        "RESOURCE_EXHAUSTED" => Code::ResourceExhausted,
        "FAILED_PRECONDITION" => Code::FailedPrecondition,
        "ABORTED" => Code::Aborted,
        "OUT_OF_RANGE" => Code::OutOfRange,
        "UNIMPLEMENTED" => Code::Unimplemented,
        "INTERNAL" => Code::Internal,
        "UNAVAILABLE" => Code::Unavailable,
        "DATA_LOSS" => Code::DataLoss,
        "UNAUTHENTICATED" => Code::Unauthenticated,
        other => {
            return Status::internal(format!(
                "env_server bug: unknown status code name {other:?}: {message}"
            ));
        }
    };
    Status::new(code, message)
}

/// The status for an exception raised by the Python service, as its `status_of` says.
pub(crate) fn from_pyerr(py: Python<'_>, service: &Py<PyAny>, err: PyErr) -> Status {
    match service
        .bind(py)
        .call_method1("status_of", (err.value(py),))
        .and_then(|s| s.extract::<(String, String)>())
    {
        Ok((code_name, message)) => from_code_name(&code_name, &message),
        Err(mapping_err) => Status::internal(format!(
            "env_server bug: {err} (and status_of failed: {mapping_err})"
        )),
    }
}

/// tonic reports a request over `max_decoding_message_size` as OUT_OF_RANGE; the
/// protocol says RESOURCE_EXHAUSTED, as grpc core does.
pub(crate) fn oversize_as_resource_exhausted(status: Status) -> Status {
    if status.code() == Code::OutOfRange
        && status
            .message()
            .starts_with("Error, decoded message length too large")
    {
        Status::resource_exhausted(format!(
            "request message too large for this server (--max-message-mb): {}",
            status.message().trim_start_matches("Error, ")
        ))
    } else {
        status
    }
}

/// The same rewrite for unary calls, whose decode errors tonic answers before any
/// handler runs, as trailers-only responses (the status in the headers).
pub(crate) fn oversize_response(
    mut response: Response<tonic::body::Body>,
) -> Response<tonic::body::Body> {
    if let Some(status) = Status::from_header_map(response.headers()) {
        let mapped = oversize_as_resource_exhausted(status.clone());
        if mapped.code() != status.code() {
            // add_header replaces grpc-status and grpc-message, percent-encoding the message.
            let _ = mapped.add_header(response.headers_mut());
        }
    }
    response
}
