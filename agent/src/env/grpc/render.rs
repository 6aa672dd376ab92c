//! The `Render` RPC on a session: proto to [`Frames`] and back.

use mo_env_proto::v1 as pb;

use super::RemoteEnv;
use super::convert::{missing, tensor_from_proto};
use crate::core::spec::DType;
use crate::env::error::EnvError;
use crate::env::frames::{Frames, RenderOptions};

impl RemoteEnv {
    /// The current RGB frames of some instances (capability "render"); the server
    /// checks sizes, camera and indices and says which field was wrong.
    pub async fn render(&self, options: &RenderOptions) -> Result<Frames, EnvError> {
        let request = pb::RenderRequest {
            session_id: self.session_id.clone(),
            env_indices: options.env_indices.iter().map(|&i| i as i32).collect(),
            width: i32::try_from(options.width).unwrap_or(i32::MAX),
            height: i32::try_from(options.height).unwrap_or(i32::MAX),
            camera: options.camera.clone(),
        };
        let r = self
            .client
            .call(
                "Render",
                self.client.deadlines.ceiling(),
                request,
                |mut c, r| async move { c.render(r).await },
            )
            .await?;
        let tensor = tensor_from_proto(
            r.frames.ok_or_else(|| missing("RenderResponse.frames"))?,
            "RenderResponse.frames",
        )?;
        match (tensor.dtype, tensor.shape.as_slice()) {
            (DType::Uint8, &[count, height, width, 3]) => Ok(Frames {
                count,
                height,
                width,
                data: tensor.data,
                cameras: r.cameras,
                fps: r.fps,
            }),
            (dtype, shape) => Err(EnvError::Protocol {
                field: "RenderResponse.frames".into(),
                expected: "uint8 [N, H, W, 3]".into(),
                got: format!("{dtype:?} {shape:?}"),
            }),
        }
    }
}
