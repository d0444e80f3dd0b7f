//! Shaded pictures of a 3-D [`Scene`]: an orthographic camera, a depth buffer and
//! Lambert shading, so solids hide what is behind them and read as solids.
//!
//! Each solid is cut into triangles whose vertices carry outward normals; a vertex's
//! brightness is `ambient + (1 − ambient)·max(0, n·l)` for one light `l` above and beside
//! the camera, interpolated across the triangle (Gouraud). Curves are drawn as depth-tested
//! lines. Beside the colours, every pixel records which body covers it ([`Picture::label`]),
//! so tests can ask where a body landed without matching shaded colours.

use std::f64::consts::{PI, TAU};

use ciflow_engine::math::Vector3;
use nalgebra::{Point3, Rotation3, Vector2};

use crate::error::EnvError;
use crate::raster::{Canvas, Rgb, View};
use crate::scene::{Scene, Shape};

/// Share of a colour that a surface turned away from the light keeps.
const AMBIENT: f64 = 0.35;
/// Facets per full turn of a round solid.
const SEGMENTS: usize = 24;

/// An orthographic camera at azimuth `φ` and elevation `e` (rad) looking at the origin,
/// showing the screen rectangle `view` ([`crate::raster::oblique_projection`]'s screen).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    pub azimuth: f64,
    pub elevation: f64,
    pub view: View,
}

impl Camera {
    /// Screen position and depth of `p`: with `v = R_z(−φ) p`, screen
    /// `(v_y, v_z cos e − v_x sin e)` and depth `v_x cos e + v_z sin e` (larger is nearer).
    fn project(&self, p: &Vector3) -> (Vector2<f64>, f64) {
        let v = Rotation3::from_euler_angles(0.0, 0.0, -self.azimuth) * p;
        let (sin_e, cos_e) = self.elevation.sin_cos();
        (
            Vector2::new(v.y, v.z * cos_e - v.x * sin_e),
            v.x * cos_e + v.z * sin_e,
        )
    }

    /// Unit vector from the scene toward the camera, in the world frame.
    fn toward_camera(&self) -> Vector3 {
        let (sin_e, cos_e) = self.elevation.sin_cos();
        Rotation3::from_euler_angles(0.0, 0.0, self.azimuth) * Vector3::new(cos_e, 0.0, sin_e)
    }

    /// The light: from the camera's side, raised and shifted to its left, so that tops
    /// and one flank of each solid are lit.
    fn light(&self) -> Vector3 {
        let left = Rotation3::from_euler_angles(0.0, 0.0, self.azimuth) * -Vector3::y();
        (self.toward_camera() + 0.8 * Vector3::z() + 0.4 * left).normalize()
    }
}

/// A rendered frame and, per pixel, the index in [`Scene::bodies`] of the body seen there.
#[derive(Clone, Debug)]
pub struct Picture {
    width: u32,
    pixels: Vec<u8>,
    labels: Vec<Option<u32>>,
}

impl Picture {
    /// RGB, row-major `height × width × 3`.
    pub fn into_pixels(self) -> Vec<u8> {
        self.pixels
    }

    /// The body seen at pixel `(x, y)` (`None`: the background).
    pub fn label(&self, x: u32, y: u32) -> Option<usize> {
        self.labels[(y * self.width + x) as usize].map(|i| i as usize)
    }

    /// The pixels `(x, y)` where body `index` is seen.
    pub fn pixels_of(&self, index: usize) -> Vec<(u32, u32)> {
        self.labels
            .iter()
            .enumerate()
            .filter(|(_, label)| **label == Some(index as u32))
            .map(|(i, _)| (i as u32 % self.width, i as u32 / self.width))
            .collect()
    }
}

/// A triangle corner: position and outward unit normal.
#[derive(Clone, Copy)]
struct Corner {
    p: Vector3,
    n: Vector3,
}

/// Renders `scene` through `camera` on a white background.
pub fn render(
    scene: &Scene,
    camera: &Camera,
    width: u32,
    height: u32,
) -> Result<Picture, EnvError> {
    let canvas = Canvas::new(width, height, camera.view)?;
    let mut pixels = canvas.clone().into_pixels();
    let mut depth = vec![f64::NEG_INFINITY; (width * height) as usize];
    let mut labels = vec![None; (width * height) as usize];
    let light = camera.light();
    for (index, body) in scene.bodies.iter().enumerate() {
        let mut paint = |x: u32, y: u32, z: f64, brightness: f64| {
            let i = (y * width + x) as usize;
            if z > depth[i] {
                depth[i] = z;
                labels[i] = Some(index as u32);
                pixels[i * 3..i * 3 + 3].copy_from_slice(&shade(body.color, brightness));
            }
        };
        if let Shape::Curve {
            points,
            closed,
            radius,
        } = &body.shape
        {
            let mut segments: Vec<_> = points.windows(2).map(|w| (w[0], w[1])).collect();
            if let (true, Some(first), Some(last)) = (closed, points.first(), points.last()) {
                segments.push((*last, *first));
            }
            let width_px = (2.0 * radius * canvas.scale()).max(1.0);
            for (a, b) in segments {
                line(&canvas, camera, &a, &b, width_px, &mut paint);
            }
            continue;
        }
        for triangle in triangles(&body.shape) {
            let corners = triangle.map(|c| {
                let (screen, z) = camera.project(&c.p);
                let brightness = AMBIENT + (1.0 - AMBIENT) * c.n.dot(&light).max(0.0);
                (canvas.to_pixel(&screen), z, brightness)
            });
            fill_triangle(width, height, &corners, &mut paint);
        }
    }
    Ok(Picture {
        width,
        pixels,
        labels,
    })
}

fn shade(color: Rgb, brightness: f64) -> Rgb {
    color.map(|c| (f64::from(c) * brightness).round().clamp(0.0, 255.0) as u8)
}

/// Paints the pixels whose centres lie in the triangle `(pixel, depth, brightness)³`,
/// interpolating depth and brightness barycentrically.
fn fill_triangle(
    width: u32,
    height: u32,
    corners: &[(Vector2<f64>, f64, f64); 3],
    paint: &mut impl FnMut(u32, u32, f64, f64),
) {
    let [(a, za, ba), (b, zb, bb), (c, zc, bc)] = *corners;
    let area = (b - a).perp(&(c - a));
    if area.abs() < 1e-12 {
        return;
    }
    let low = a.inf(&b).inf(&c);
    let high = a.sup(&b).sup(&c);
    let x0 = low.x.floor().max(0.0) as u32;
    let y0 = low.y.floor().max(0.0) as u32;
    let x1 = (high.x.ceil().max(0.0) as u32).min(width);
    let y1 = (high.y.ceil().max(0.0) as u32).min(height);
    for y in y0..y1 {
        for x in x0..x1 {
            let p = Vector2::new(x as f64 + 0.5, y as f64 + 0.5);
            let wa = (c - b).perp(&(p - b)) / area;
            let wb = (a - c).perp(&(p - c)) / area;
            let wc = 1.0 - wa - wb;
            if wa >= 0.0 && wb >= 0.0 && wc >= 0.0 {
                paint(
                    x,
                    y,
                    wa * za + wb * zb + wc * zc,
                    wa * ba + wb * bb + wc * bc,
                );
            }
        }
    }
}

/// A depth-tested segment `a–b`, `width` pixels thick, unshaded.
fn line(
    canvas: &Canvas,
    camera: &Camera,
    a: &Vector3,
    b: &Vector3,
    width: f64,
    paint: &mut impl FnMut(u32, u32, f64, f64),
) {
    let ((sa, za), (sb, zb)) = (camera.project(a), camera.project(b));
    let (pa, pb) = (canvas.to_pixel(&sa), canvas.to_pixel(&sb));
    let samples = ((pb - pa).norm() * 2.0).ceil().max(1.0) as usize;
    let half = width / 2.0;
    let (w, h) = canvas.size();
    for k in 0..=samples {
        let t = k as f64 / samples as f64;
        let centre = pa + t * (pb - pa);
        let z = za + t * (zb - za);
        let x0 = (centre.x - half).floor().max(0.0) as u32;
        let y0 = (centre.y - half).floor().max(0.0) as u32;
        let x1 = ((centre.x + half).ceil().max(0.0) as u32).min(w);
        let y1 = ((centre.y + half).ceil().max(0.0) as u32).min(h);
        for y in y0..y1 {
            for x in x0..x1 {
                let p = Vector2::new(x as f64 + 0.5, y as f64 + 0.5);
                if (p - centre).norm() <= half.max(0.5) {
                    paint(x, y, z, 1.0);
                }
            }
        }
    }
}

/// The triangles of a solid (none for a curve).
fn triangles(shape: &Shape) -> Vec<[Corner; 3]> {
    match shape {
        Shape::Sphere { centre, radius } => sphere(centre, *radius),
        Shape::Capsule { from, to, radius } => {
            let mut all = tube(from, to, *radius);
            all.extend(sphere(from, *radius));
            all.extend(sphere(to, *radius));
            all
        }
        Shape::Cylinder {
            pose,
            radius,
            height,
        } => {
            let base = pose.translation.vector;
            let axis = pose.rotation * Vector3::z();
            let top = base + *height * axis;
            let mut all = tube(&base, &top, *radius);
            all.extend(disc(&base, &-axis, *radius));
            all.extend(disc(&top, &axis, *radius));
            all
        }
        Shape::Cuboid { pose, half_extents } => {
            let mut all = Vec::with_capacity(12);
            for axis in 0..3 {
                for sign in [-1.0, 1.0] {
                    let mut n = Vector3::zeros();
                    n[axis] = sign;
                    let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
                    let corner = |su: f64, sv: f64| {
                        let mut local = n.component_mul(half_extents);
                        local[u] = su * half_extents[u];
                        local[v] = sv * half_extents[v];
                        Corner {
                            p: (pose * Point3::from(local)).coords,
                            n: pose.rotation * n,
                        }
                    };
                    let quad = [
                        corner(-1.0, -1.0),
                        corner(1.0, -1.0),
                        corner(1.0, 1.0),
                        corner(-1.0, 1.0),
                    ];
                    all.push([quad[0], quad[1], quad[2]]);
                    all.push([quad[0], quad[2], quad[3]]);
                }
            }
            all
        }
        Shape::Curve { .. } => Vec::new(),
    }
}

/// Two unit vectors completing `axis` (unit) to an orthonormal frame.
fn perpendiculars(axis: &Vector3) -> (Vector3, Vector3) {
    let helper = if axis.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let u = axis.cross(&helper).normalize();
    (u, axis.cross(&u))
}

/// The side of a cylinder of `radius` from `a` to `b`, without its ends.
fn tube(a: &Vector3, b: &Vector3, radius: f64) -> Vec<[Corner; 3]> {
    let length = (b - a).norm();
    if length < 1e-12 {
        return Vec::new();
    }
    let (u, v) = perpendiculars(&((b - a) / length));
    let ring = |k: usize| {
        let angle = TAU * k as f64 / SEGMENTS as f64;
        u * angle.cos() + v * angle.sin()
    };
    (0..SEGMENTS)
        .flat_map(|k| {
            let (n0, n1) = (ring(k), ring(k + 1));
            let at = |end: &Vector3, n: Vector3| Corner {
                p: end + radius * n,
                n,
            };
            [
                [at(a, n0), at(b, n0), at(b, n1)],
                [at(a, n0), at(b, n1), at(a, n1)],
            ]
        })
        .collect()
}

/// A flat disc of `radius` at `centre` facing `normal` (unit).
fn disc(centre: &Vector3, normal: &Vector3, radius: f64) -> Vec<[Corner; 3]> {
    let (u, v) = perpendiculars(normal);
    let rim = |k: usize| {
        let angle = TAU * k as f64 / SEGMENTS as f64;
        Corner {
            p: centre + radius * (u * angle.cos() + v * angle.sin()),
            n: *normal,
        }
    };
    let middle = Corner {
        p: *centre,
        n: *normal,
    };
    (0..SEGMENTS)
        .map(|k| [middle, rim(k), rim(k + 1)])
        .collect()
}

/// A sphere as latitude–longitude quads.
fn sphere(centre: &Vector3, radius: f64) -> Vec<[Corner; 3]> {
    let rings = SEGMENTS / 2;
    let at = |i: usize, j: usize| {
        let (polar, azimuth) = (
            PI * i as f64 / rings as f64,
            TAU * j as f64 / SEGMENTS as f64,
        );
        let n = Vector3::new(
            polar.sin() * azimuth.cos(),
            polar.sin() * azimuth.sin(),
            polar.cos(),
        );
        Corner {
            p: centre + radius * n,
            n,
        }
    };
    (0..rings)
        .flat_map(|i| (0..SEGMENTS).map(move |j| (i, j)))
        .flat_map(|(i, j)| {
            [
                [at(i, j), at(i + 1, j), at(i + 1, j + 1)],
                [at(i, j), at(i + 1, j + 1), at(i, j + 1)],
            ]
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::Body;

    const CAMERA: Camera = Camera {
        azimuth: 0.0,
        elevation: 0.0,
        view: View {
            min: Vector2::new(-1.0, -1.0),
            max: Vector2::new(1.0, 1.0),
        },
    };

    fn sphere_at(x: f64, y: f64, radius: f64, color: Rgb) -> Body {
        Body::new(
            "ball",
            Shape::Sphere {
                centre: Vector3::new(x, y, 0.0),
                radius,
            },
            color,
        )
    }

    #[test]
    fn the_nearer_solid_hides_the_farther_in_either_drawing_order() {
        // Seen from +x: the sphere at x = 0.5 is in front of the one at x = −0.5.
        let near = Body::new(
            "near",
            Shape::Sphere {
                centre: Vector3::new(0.5, 0.0, 0.0),
                radius: 0.3,
            },
            [200, 0, 0],
        );
        let far = Body::new(
            "far",
            Shape::Sphere {
                centre: Vector3::new(-0.5, 0.0, 0.0),
                radius: 0.5,
            },
            [0, 0, 200],
        );
        for bodies in [vec![near.clone(), far.clone()], vec![far, near]] {
            let scene = Scene { bodies };
            let near_index = scene.bodies.iter().position(|b| b.name == "near").unwrap();
            let picture = render(&scene, &CAMERA, 100, 100).unwrap();
            assert_eq!(picture.label(50, 50), Some(near_index), "the centre");
            // Outside the near sphere's disc but inside the far one's.
            assert_eq!(picture.label(50, 30), Some(1 - near_index));
            assert_eq!(picture.label(2, 2), None);
        }
    }

    #[test]
    fn a_sphere_is_lit_on_the_side_facing_the_light_and_covers_its_disc() {
        let scene = Scene {
            bodies: vec![sphere_at(0.0, 0.0, 0.5, [200, 200, 200])],
        };
        let picture = render(&scene, &CAMERA, 101, 101).unwrap();
        let covered = picture.pixels_of(0).len() as f64;
        let disc = PI * (0.5 * 50.5_f64).powi(2);
        assert!((covered / disc - 1.0).abs() < 0.05, "{covered} vs {disc}");
        let pixels = picture.into_pixels();
        let brightness = |x: usize, y: usize| pixels[(y * 101 + x) * 3];
        // The light comes from above and the camera's left: the upper-left is brighter
        // than the lower-right.
        assert!(brightness(40, 35) > brightness(62, 66) + 30);
    }

    #[test]
    fn curves_are_drawn_and_hidden_by_solids_in_front() {
        let curve = Body::new(
            "curve",
            Shape::Curve {
                points: vec![Vector3::new(-0.5, -0.9, 0.0), Vector3::new(-0.5, 0.9, 0.0)],
                closed: false,
                radius: 0.01,
            },
            [0, 0, 0],
        );
        let scene = Scene {
            bodies: vec![curve, sphere_at(0.5, 0.5, 0.2, [200, 0, 0])],
        };
        let picture = render(&scene, &CAMERA, 100, 100).unwrap();
        // The curve runs across the screen's middle row; the sphere, nearer the camera,
        // covers it around screen x = 0.5 (pixel 75).
        assert_eq!(picture.label(10, 50), Some(0));
        assert_eq!(picture.label(75, 50), Some(1));
    }
}
