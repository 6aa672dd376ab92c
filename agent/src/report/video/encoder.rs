//! Encoding RGB frames to a video file with the `ffmpeg` binary, fed raw frames over a
//! pipe (no hand-written codec): the one from the pinned `imageio-ffmpeg` wheel in the
//! project's venv, or any `ffmpeg` the user names.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, Stdio};

use super::VideoError;
use crate::env::server_process::default_python;

/// Where to find ffmpeg, in order: `$IMAGEIO_FFMPEG_EXE` (imageio's own variable), the
/// `imageio_ffmpeg` package of the env server's Python (`scripts/setup.sh` installs it),
/// then `ffmpeg` on PATH.
pub fn find_ffmpeg() -> Result<PathBuf, VideoError> {
    let mut tried = Vec::new();
    if let Some(path) = std::env::var_os("IMAGEIO_FFMPEG_EXE") {
        return Ok(PathBuf::from(path));
    }
    let python = default_python();
    let asked = Command::new(&python)
        .args([
            "-c",
            "import imageio_ffmpeg; print(imageio_ffmpeg.get_ffmpeg_exe())",
        ])
        .stderr(Stdio::null())
        .output();
    match asked {
        Ok(out) if out.status.success() => {
            let path = PathBuf::from(String::from_utf8_lossy(&out.stdout).trim());
            if path.is_file() {
                return Ok(path);
            }
            tried.push(format!("{} (not a file)", path.display()));
        }
        _ => tried.push(format!("imageio_ffmpeg in {}", python.display())),
    }
    let on_path = Command::new("ffmpeg")
        .arg("-version")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status();
    if on_path.is_ok_and(|s| s.success()) {
        return Ok(PathBuf::from("ffmpeg"));
    }
    tried.push("ffmpeg on PATH".into());
    Err(VideoError::NoEncoder(tried.join(", ")))
}

/// One video being written: ffmpeg reads rgb24 frames of one size on its stdin.
#[derive(Debug)]
pub struct Encoder {
    child: Child,
    stdin: Option<ChildStdin>,
    path: PathBuf,
    frame_bytes: usize,
    /// Frames written so far.
    pub frames: usize,
}

impl Encoder {
    /// Start ffmpeg writing `path` (its extension picks the container: .mp4, .webm,
    /// .gif, ...) from `width` x `height` frames (both even for H.264) at `fps`.
    pub fn open(
        ffmpeg: &Path,
        path: &Path,
        width: usize,
        height: usize,
        fps: f64,
    ) -> Result<Self, VideoError> {
        let size = format!("{width}x{height}");
        let rate = format!("{fps}");
        let mut command = Command::new(ffmpeg);
        command.args([
            "-y",
            "-loglevel",
            "error",
            "-f",
            "rawvideo",
            "-pix_fmt",
            "rgb24",
        ]);
        command.args(["-s", &size, "-r", &rate, "-i", "-", "-an"]);
        if path.extension().is_some_and(|e| e == "mp4" || e == "mkv") {
            // H.264 in yuv420p: what browsers and players expect of an .mp4.
            command.args(["-c:v", "libx264", "-pix_fmt", "yuv420p", "-crf", "23"]);
        }
        let mut child = command
            .arg(path)
            .stdin(Stdio::piped())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|e| VideoError::Encoder {
                path: path.to_path_buf(),
                message: format!("cannot run {}: {e}", ffmpeg.display()),
            })?;
        let stdin = child.stdin.take();
        Ok(Self {
            child,
            stdin,
            path: path.to_path_buf(),
            frame_bytes: width * height * 3,
            frames: 0,
        })
    }

    /// Append one frame of `width * height * 3` RGB bytes.
    pub fn write(&mut self, rgb: &[u8]) -> Result<(), VideoError> {
        assert_eq!(rgb.len(), self.frame_bytes, "frame of the video's size");
        let stdin = self.stdin.as_mut().expect("open until finish");
        if stdin.write_all(rgb).is_err() {
            // ffmpeg exited; its stderr says why.
            return Err(self.failure());
        }
        self.frames += 1;
        Ok(())
    }

    /// Close the input and wait for ffmpeg to finish the file; returns its path.
    pub fn finish(mut self) -> Result<PathBuf, VideoError> {
        drop(self.stdin.take());
        let status = self.child.wait().map_err(|e| VideoError::Encoder {
            path: self.path.clone(),
            message: e.to_string(),
        })?;
        if !status.success() {
            return Err(self.failure());
        }
        Ok(std::mem::take(&mut self.path))
    }

    fn failure(&mut self) -> VideoError {
        drop(self.stdin.take());
        let _ = self.child.wait();
        let mut stderr = String::new();
        if let Some(mut pipe) = self.child.stderr.take() {
            let _ = std::io::Read::read_to_string(&mut pipe, &mut stderr);
        }
        VideoError::Encoder {
            path: self.path.clone(),
            message: format!("ffmpeg failed: {}", stderr.trim()),
        }
    }
}

impl Drop for Encoder {
    fn drop(&mut self) {
        if self.stdin.take().is_some() {
            // Dropped without finish (an error elsewhere): do not leave ffmpeg running.
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}
