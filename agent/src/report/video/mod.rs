//! Videos of a policy: frames from the server's `Render`, tiled for the B instances of
//! an evaluation session, with each objective's running return written under its
//! frame, encoded by ffmpeg (`encoder`). `eval --video`, `train --video-every` and
//! `sweep --video` record through [`Recorder`] (`eval::EvalObserver` drives it).

mod canvas;
mod encoder;

use std::path::{Path, PathBuf};

pub use canvas::{Caption, Layout};
pub use encoder::{Encoder, find_ffmpeg};

use crate::env::StepResult;
use crate::env::error::EnvError;
use crate::env::frames::RenderOptions;
use crate::env::grpc::RemoteEnv;

/// At most this many instances are tiled into one video (a 4 x 4 grid).
pub const MAX_TILES: usize = 16;
/// Playback rate when neither the options nor the env give one.
const DEFAULT_FPS: f64 = 30.0;

/// Errors while recording a video.
#[derive(Debug, thiserror::Error)]
pub enum VideoError {
    /// Talking to the env server failed (a Render the server refused says why).
    #[error(transparent)]
    Env(#[from] EnvError),
    /// No ffmpeg binary was found.
    #[error(
        "no ffmpeg to encode videos with (tried {0}); run scripts/setup.sh (it installs the \
         imageio-ffmpeg wheel into .venv), or set IMAGEIO_FFMPEG_EXE to an ffmpeg binary"
    )]
    NoEncoder(String),
    /// ffmpeg failed or could not be started.
    #[error("video {path}: {message}")]
    Encoder {
        /// The video being written.
        path: PathBuf,
        /// What went wrong (ffmpeg's own message when it has one).
        message: String,
    },
    /// Drawing the captions failed.
    #[error("drawing a video frame: {0}")]
    Draw(String),
    /// The video's directory could not be made.
    #[error("{path}: {source}")]
    Io {
        /// Directory involved.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
}

/// How each instance is rendered and how fast the video plays.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct VideoOptions {
    /// Width of each instance's frame in pixels; 0 = the server's default (320).
    pub width: u32,
    /// Height of each instance's frame; 0 = the server's default (240).
    pub height: u32,
    /// Camera name; "" = the task's default view.
    pub camera: String,
    /// Frames per second; None = the task's real time (30 when it does not say).
    pub fps: Option<f64>,
}

/// Records an evaluation: one video frame per step, the first `MAX_TILES` instances tiled.
#[derive(Debug)]
pub struct Recorder {
    path: PathBuf,
    options: VideoOptions,
    ffmpeg: PathBuf,
    objectives: Vec<String>,
    tiles: usize,
    writer: Option<(Encoder, Layout)>,
    returns: Vec<Vec<f64>>,
    steps: Vec<u64>,
    episodes: Vec<u64>,
}

impl Recorder {
    /// A recorder writing `path` for a session of `num_envs` instances with these
    /// objectives. Finds ffmpeg now, so a missing encoder fails before any episode runs.
    pub fn new(
        path: &Path,
        options: VideoOptions,
        objectives: Vec<String>,
        num_envs: usize,
    ) -> Result<Self, VideoError> {
        let ffmpeg = find_ffmpeg()?;
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(|source| VideoError::Io {
                path: dir.to_path_buf(),
                source,
            })?;
        }
        let tiles = num_envs.clamp(1, MAX_TILES);
        let k = objectives.len();
        Ok(Self {
            path: path.to_path_buf(),
            options,
            ffmpeg,
            objectives,
            tiles,
            writer: None,
            returns: vec![vec![0.0; k]; tiles],
            steps: vec![0; tiles],
            episodes: vec![0; tiles],
        })
    }

    /// Render the tiled instances and append one video frame.
    async fn capture(&mut self, env: &RemoteEnv) -> Result<(), VideoError> {
        let frames = env
            .render(&RenderOptions {
                env_indices: (0..self.tiles).collect(),
                width: self.options.width,
                height: self.options.height,
                camera: self.options.camera.clone(),
            })
            .await?;
        let captions = self.captions();
        if self.writer.is_none() {
            let layout = Layout::new(
                self.tiles,
                frames.width,
                frames.height,
                self.objectives.len(),
            );
            let fps = self
                .options
                .fps
                .or((frames.fps > 0.0).then_some(frames.fps))
                .unwrap_or(DEFAULT_FPS);
            let encoder =
                Encoder::open(&self.ffmpeg, &self.path, layout.width, layout.height, fps)?;
            self.writer = Some((encoder, layout));
        }
        let (encoder, layout) = self.writer.as_mut().expect("opened above");
        encoder.write(&layout.compose(&frames, &captions)?)?;
        Ok(())
    }

    fn captions(&self) -> Vec<Caption> {
        let width = self.objectives.iter().map(String::len).max().unwrap_or(0);
        (0..self.tiles)
            .map(|i| Caption {
                title: format!(
                    "env {i}  episode {}  step {}",
                    self.episodes[i] + 1,
                    self.steps[i]
                ),
                lines: self
                    .objectives
                    .iter()
                    .zip(&self.returns[i])
                    .map(|(name, value)| format!("{name:<width$}  {value:>9.2}"))
                    .collect(),
            })
            .collect()
    }

    /// Finish the file.
    pub fn finish(self) -> Result<VideoReport, VideoError> {
        match self.writer {
            Some((encoder, _)) => {
                let frames = encoder.frames;
                Ok(VideoReport {
                    path: encoder.finish()?,
                    frames,
                })
            }
            None => Ok(VideoReport {
                path: self.path,
                frames: 0,
            }),
        }
    }
}

impl Recorder {
    /// The session was just reset: its first frame.
    pub async fn record_reset(&mut self, env: &RemoteEnv) -> Result<(), VideoError> {
        self.capture(env).await
    }

    /// The session just took `step`: its frame, under the running returns.
    pub async fn record_step(
        &mut self,
        env: &RemoteEnv,
        step: &StepResult,
    ) -> Result<(), VideoError> {
        let k = self.objectives.len();
        for i in 0..self.tiles {
            self.steps[i] += 1;
            for (total, r) in self.returns[i]
                .iter_mut()
                .zip(&step.reward[i * k..(i + 1) * k])
            {
                *total += f64::from(*r);
            }
        }
        // The frame after an episode's last step shows its full return (with SAME_STEP
        // autoreset the picture is already the next episode's first); then it starts over.
        self.capture(env).await?;
        for e in step.episodes.iter().filter(|e| e.env_index < self.tiles) {
            self.returns[e.env_index].fill(0.0);
            self.steps[e.env_index] = 0;
            self.episodes[e.env_index] += 1;
        }
        Ok(())
    }
}

/// What a recorded video holds, for the CLI's report.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct VideoReport {
    /// The file written.
    pub path: PathBuf,
    /// Video frames in it.
    pub frames: usize,
}

/// What a training run records.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct VideoPlan {
    /// Env steps between videos during training; None = only the final evaluation's.
    pub every: Option<u64>,
    /// Frame size, camera and rate.
    pub options: VideoOptions,
}
