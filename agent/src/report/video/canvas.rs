//! One video frame: the instances' rendered frames tiled in a grid, each with its
//! episode, step and the objectives' running returns written under it (plotters'
//! bitmap backend with the embedded DejaVu Sans, as the figures use).

use plotters::prelude::*;

use super::VideoError;
use crate::env::frames::Frames;

/// The text under one tile: a title line, then one line per objective.
#[derive(Debug, Clone, PartialEq)]
pub struct Caption {
    /// e.g. `env 0  episode 2  step 37`.
    pub title: String,
    /// e.g. `treasure   8.20`, one per objective.
    pub lines: Vec<String>,
}

/// Where tiles and captions go on the video frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Layout {
    tile_width: usize,
    tile_height: usize,
    columns: usize,
    font_px: u32,
    caption_height: usize,
    /// Video frame width (even, as H.264 in yuv420p needs).
    pub width: usize,
    /// Video frame height (even).
    pub height: usize,
}

const BACKGROUND: RGBColor = RGBColor(18, 18, 24);
const TEXT: RGBColor = RGBColor(235, 235, 235);

impl Layout {
    /// `tiles` frames of `tile_width` x `tile_height` in a near-square grid, each with
    /// room for a title and `objectives` lines of text under it.
    pub fn new(tiles: usize, tile_width: usize, tile_height: usize, objectives: usize) -> Self {
        let columns = (tiles as f64).sqrt().ceil().max(1.0) as usize;
        let rows = tiles.div_ceil(columns).max(1);
        let font_px = (tile_width / 24).clamp(10, 18) as u32;
        let caption_height = (font_px as usize + 4) * (objectives + 1) + 6;
        let even = |n: usize| n + n % 2;
        Self {
            tile_width,
            tile_height,
            columns,
            font_px,
            caption_height,
            width: even(columns * tile_width),
            height: even(rows * (tile_height + caption_height)),
        }
    }

    /// The video frame (RGB bytes, `height * width * 3`) for `frames`, one caption each.
    pub fn compose(&self, frames: &Frames, captions: &[Caption]) -> Result<Vec<u8>, VideoError> {
        crate::report::font::register();
        let mut canvas = vec![0u8; self.width * self.height * 3];
        for pixel in canvas.chunks_exact_mut(3) {
            pixel.copy_from_slice(&[BACKGROUND.0, BACKGROUND.1, BACKGROUND.2]);
        }
        let cell_height = self.tile_height + self.caption_height;
        for i in 0..frames.count {
            let (x0, y0) = (
                (i % self.columns) * self.tile_width,
                (i / self.columns) * cell_height,
            );
            let frame = frames.frame(i);
            let row_bytes = self.tile_width * 3;
            for y in 0..self.tile_height.min(frames.height) {
                let src = &frame[y * frames.width * 3..][..row_bytes.min(frames.width * 3)];
                let dst = ((y0 + y) * self.width + x0) * 3;
                canvas[dst..dst + src.len()].copy_from_slice(src);
            }
        }
        self.draw_captions(&mut canvas, captions)
            .map_err(|e| VideoError::Draw(e.to_string()))?;
        Ok(canvas)
    }

    fn draw_captions(
        &self,
        canvas: &mut [u8],
        captions: &[Caption],
    ) -> Result<(), Box<dyn std::error::Error>> {
        let root = BitMapBackend::with_buffer(canvas, (self.width as u32, self.height as u32))
            .into_drawing_area();
        let style = ("sans-serif", self.font_px).into_font().color(&TEXT);
        let line = self.font_px as usize + 4;
        let cell_height = self.tile_height + self.caption_height;
        for (i, caption) in captions.iter().enumerate() {
            let x = (i % self.columns) * self.tile_width + 6;
            let y = (i / self.columns) * cell_height + self.tile_height + 4;
            for (n, text) in std::iter::once(&caption.title)
                .chain(&caption.lines)
                .enumerate()
            {
                root.draw(&Text::new(
                    text.as_str(),
                    (x as i32, (y + n * line) as i32),
                    style.clone(),
                ))?;
            }
        }
        root.present()?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frames(count: usize, width: usize, height: usize) -> Frames {
        Frames {
            count,
            height,
            width,
            data: vec![200; count * width * height * 3],
            cameras: Vec::new(),
            fps: 0.0,
        }
    }

    #[test]
    fn tiles_in_a_near_square_grid_with_even_sides() {
        let layout = Layout::new(3, 65, 40, 2);
        assert_eq!(
            (layout.columns, layout.width % 2, layout.height % 2),
            (2, 0, 0)
        );
        assert_eq!(layout.width, 130);
        assert_eq!(layout.height, 2 * (40 + layout.caption_height));
    }

    #[test]
    fn frames_land_in_their_tiles_and_captions_are_drawn() {
        let layout = Layout::new(2, 64, 48, 2);
        let caption = Caption {
            title: "env 0  episode 1  step 3".into(),
            lines: vec!["time  -3.00".into(), "treasure  8.20".into()],
        };
        let canvas = layout
            .compose(&frames(2, 64, 48), &[caption.clone(), caption])
            .expect("composes");
        let at = |x: usize, y: usize| &canvas[(y * layout.width + x) * 3..][..3];
        assert_eq!(at(10, 10), &[200, 200, 200]); // first tile
        assert_eq!(at(64 + 10, 10), &[200, 200, 200]); // second tile
        let caption_area = (48 * layout.width * 3)..canvas.len();
        let lit = canvas[caption_area]
            .chunks_exact(3)
            .filter(|p| p[0] > 128)
            .count();
        assert!(lit > 50, "caption text drawn ({lit} bright pixels)");
    }
}
