//! A small software rasteriser for `render()`: RGB frames of 2-D scenes.
//!
//! Shapes are given in world coordinates; a [`View`] maps the world rectangle onto the
//! frame with equal scales on both axes (the world's `y` points up, the image's down).
//! Coverage is tested per pixel centre, which is exact enough for line drawings.

use nalgebra::{Rotation3, Vector2, Vector3};

use crate::env::EnvError;

pub type Rgb = [u8; 3];

pub const WHITE: Rgb = [255, 255, 255];
pub const BLACK: Rgb = [0, 0, 0];
pub const GREY: Rgb = [150, 150, 150];
pub const LIGHT_GREY: Rgb = [225, 225, 225];
pub const BLUE: Rgb = [31, 119, 180];
pub const ORANGE: Rgb = [255, 127, 14];
pub const GREEN: Rgb = [44, 160, 44];
pub const RED: Rgb = [214, 39, 40];

/// Orthographic projection onto the screen of a camera at azimuth `φ` and elevation `e`
/// (rad) looking at the origin: with `v = R_z(−φ) p` (the camera on the `+x` axis),
/// `s = (v_y, v_z cos e − v_x sin e)`, so nearer points appear lower.
pub fn oblique_projection(p: &Vector3<f64>, azimuth: f64, elevation: f64) -> Vector2<f64> {
    let v = Rotation3::from_euler_angles(0.0, 0.0, -azimuth) * p;
    let (sin_e, cos_e) = elevation.sin_cos();
    Vector2::new(v.y, v.z * cos_e - v.x * sin_e)
}

/// The world rectangle `[x_min, x_max] × [y_min, y_max]` shown in a frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct View {
    pub min: Vector2<f64>,
    pub max: Vector2<f64>,
}

/// An RGB frame, row-major `height × width × 3`, with a world-to-pixel mapping.
#[derive(Clone, Debug)]
pub struct Canvas {
    width: u32,
    height: u32,
    pixels: Vec<u8>,
    /// Pixels per world unit.
    scale: f64,
    /// Pixel position of the world origin.
    origin: Vector2<f64>,
}

impl Canvas {
    /// A white frame showing `view`, centred, with equal axis scales; refuses a size
    /// without pixels.
    pub fn new(width: u32, height: u32, view: View) -> Result<Self, EnvError> {
        if width == 0 || height == 0 {
            return Err(EnvError::InvalidOption {
                name: "render size".into(),
                detail: format!("{width} × {height} has no pixels"),
            });
        }
        let extent = view.max - view.min;
        let scale = (width as f64 / extent.x).min(height as f64 / extent.y);
        let centre = (view.min + view.max) / 2.0;
        let origin = Vector2::new(
            width as f64 / 2.0 - scale * centre.x,
            height as f64 / 2.0 + scale * centre.y,
        );
        Ok(Self {
            width,
            height,
            pixels: vec![255; width as usize * height as usize * 3],
            scale,
            origin,
        })
    }

    pub fn into_pixels(self) -> Vec<u8> {
        self.pixels
    }

    /// Width and height in pixels.
    pub fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// Pixels per world unit.
    pub fn scale(&self) -> f64 {
        self.scale
    }

    /// Colours pixel `(x, y)`, which must lie in the frame.
    pub fn put(&mut self, x: u32, y: u32, color: Rgb) {
        let i = (y as usize * self.width as usize + x as usize) * 3;
        self.pixels[i..i + 3].copy_from_slice(&color);
    }

    /// Where the world point `p` lands, in pixel coordinates (`y` down).
    pub fn to_pixel(&self, p: &Vector2<f64>) -> Vector2<f64> {
        Vector2::new(
            self.origin.x + self.scale * p.x,
            self.origin.y - self.scale * p.y,
        )
    }

    /// Colours every pixel whose centre satisfies `inside`, within a pixel bounding box.
    fn fill_where(
        &mut self,
        low: Vector2<f64>,
        high: Vector2<f64>,
        color: Rgb,
        inside: impl Fn(Vector2<f64>) -> bool,
    ) {
        let clamp_x = |v: f64| v.clamp(0.0, self.width as f64) as u32;
        let clamp_y = |v: f64| v.clamp(0.0, self.height as f64) as u32;
        let (x0, x1) = (clamp_x(low.x.floor()), clamp_x(high.x.ceil()));
        let (y0, y1) = (clamp_y(low.y.floor()), clamp_y(high.y.ceil()));
        for y in y0..y1 {
            for x in x0..x1 {
                if inside(Vector2::new(x as f64 + 0.5, y as f64 + 0.5)) {
                    self.put(x, y, color);
                }
            }
        }
    }

    /// A segment `a–b`, `width` pixels thick.
    pub fn line(&mut self, a: &Vector2<f64>, b: &Vector2<f64>, color: Rgb, width: f64) {
        let (pa, pb) = (self.to_pixel(a), self.to_pixel(b));
        let half = width.max(1.0) / 2.0;
        let pad = Vector2::repeat(half + 1.0);
        let ab = pb - pa;
        let length_squared = ab.norm_squared();
        self.fill_where(pa.inf(&pb) - pad, pa.sup(&pb) + pad, color, |p| {
            let t = if length_squared > 0.0 {
                ((p - pa).dot(&ab) / length_squared).clamp(0.0, 1.0)
            } else {
                0.0
            };
            (p - (pa + t * ab)).norm() <= half
        });
    }

    /// A polyline through `points`, closed back to the first point if `closed`.
    pub fn polyline(&mut self, points: &[Vector2<f64>], closed: bool, color: Rgb, width: f64) {
        for pair in points.windows(2) {
            self.line(&pair[0], &pair[1], color, width);
        }
        if let (true, Some(first), Some(last)) = (closed, points.first(), points.last()) {
            self.line(last, first, color, width);
        }
    }

    /// A filled disc of world radius `radius`.
    pub fn disc(&mut self, center: &Vector2<f64>, radius: f64, color: Rgb) {
        let c = self.to_pixel(center);
        let r = (radius * self.scale).max(1.0);
        let pad = Vector2::repeat(r + 1.0);
        self.fill_where(c - pad, c + pad, color, |p| (p - c).norm() <= r);
    }

    /// A circle of world radius `radius`, `width` pixels thick.
    pub fn circle(&mut self, center: &Vector2<f64>, radius: f64, color: Rgb, width: f64) {
        let c = self.to_pixel(center);
        let r = radius * self.scale;
        let half = width.max(1.0) / 2.0;
        let pad = Vector2::repeat(r + half + 1.0);
        self.fill_where(c - pad, c + pad, color, |p| {
            ((p - c).norm() - r).abs() <= half
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pixel(canvas: &Canvas, x: u32, y: u32) -> Rgb {
        let i = (y as usize * canvas.width as usize + x as usize) * 3;
        [canvas.pixels[i], canvas.pixels[i + 1], canvas.pixels[i + 2]]
    }

    #[test]
    fn world_y_points_up_and_shapes_land_where_expected() {
        let view = View {
            min: Vector2::new(-1.0, -1.0),
            max: Vector2::new(1.0, 1.0),
        };
        let mut canvas = Canvas::new(100, 100, view).unwrap();
        canvas.disc(&Vector2::new(0.5, 0.5), 0.1, RED);
        canvas.line(
            &Vector2::new(-1.0, -0.5),
            &Vector2::new(1.0, -0.5),
            BLUE,
            3.0,
        );
        assert_eq!(pixel(&canvas, 75, 25), RED);
        assert_eq!(pixel(&canvas, 25, 75), BLUE);
        assert_eq!(pixel(&canvas, 25, 25), WHITE);
        assert_eq!(canvas.into_pixels().len(), 100 * 100 * 3);
    }
}
