//! Rendered frames as the agent sees them: what to ask a session for, and the RGB
//! pixels that come back (the `Render` RPC, capability "render").

/// What to render: which instances, how large, from which camera.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct RenderOptions {
    /// Instances to render, in this order; empty = all B.
    pub env_indices: Vec<usize>,
    /// Frame width in pixels; 0 = the server's default (320).
    pub width: u32,
    /// Frame height in pixels; 0 = the server's default (240).
    pub height: u32,
    /// A camera the env names; "" = the task's default view.
    pub camera: String,
}

/// N RGB frames of one size: `data` is uint8 `[count, height, width, 3]`, top row first.
#[derive(Debug, Clone, PartialEq)]
pub struct Frames {
    /// Number of frames N.
    pub count: usize,
    /// Rows per frame.
    pub height: usize,
    /// Columns per frame.
    pub width: usize,
    /// `count * height * width * 3` bytes.
    pub data: Vec<u8>,
    /// The env's named cameras, besides the default "".
    pub cameras: Vec<String>,
    /// Frames per second that play the task in real time; 0 when the env does not say.
    pub fps: f64,
}

impl Frames {
    /// The RGB bytes of frame `i`, `[height, width, 3]`.
    pub fn frame(&self, i: usize) -> &[u8] {
        let size = self.height * self.width * 3;
        &self.data[i * size..(i + 1) * size]
    }
}
