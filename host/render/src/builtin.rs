//! Built-in objects that need no downloads: a slab (box), a UV sphere, the
//! Utah teapot tessellated from its Bezier patches, and a bread slice (a
//! procedural slice outline extruded with rounded edges). All in mm, z up,
//! resting on z = 0 (the slab's top face is z = 0).

use std::f32::consts::{PI, TAU};

use glam::{Vec2, Vec3};

use crate::error::{MeshError, RenderError};
use crate::mesh::Mesh;
use crate::mesh_input::MeshInput;
use crate::teapot_data::{PATCHES, POINTS};
use crate::watertight::{cap_holes, union_surface};

/// The built-in teapot's grid, in teapot units (0.84 mm at 12 mm per unit).
pub const TEAPOT_CELL: f32 = 0.07;

/// Names accepted by [`builtin_mesh`].
pub const BUILTIN_NAMES: [&str; 4] = ["slab", "sphere", "teapot", "bread"];

/// Builds a built-in object by name with its default size.
pub fn builtin_mesh(name: &str) -> Result<Mesh, RenderError> {
    let mesh = match name {
        "slab" => slab(60.0, 10.0),
        "sphere" => sphere(20.0, 96, 48),
        "teapot" => teapot(12.0, TEAPOT_CELL),
        "bread" => bread(12.0),
        _ => return Err(RenderError::UnknownBuiltin(name.to_string())),
    };
    Ok(mesh?)
}

/// A `size` x `size` x `thickness` box whose top face is z = 0, centred on
/// the z axis (the flat sample of the rig).
pub fn slab(size: f32, thickness: f32) -> Result<Mesh, MeshError> {
    let h = size / 2.0;
    box_mesh(Vec3::new(-h, -h, -thickness), Vec3::new(h, h, 0.0))
}

/// An axis-aligned box with per-face vertices (sharp edges).
pub fn box_mesh(lo: Vec3, hi: Vec3) -> Result<Mesh, MeshError> {
    let mut m = MeshInput::default();
    let mut normals = Vec::new();
    // Each face: normal axis, sign; corners listed counter-clockwise seen from outside.
    for axis in 0..3 {
        for sign in [-1.0f32, 1.0] {
            let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
            let mut n = Vec3::ZERO;
            n[axis] = sign;
            let base = m.positions.len() as u32;
            for (a, b) in [(0, 0), (1, 0), (1, 1), (0, 1)] {
                let mut p = Vec3::ZERO;
                p[axis] = if sign > 0.0 { hi[axis] } else { lo[axis] };
                p[u] = if a == 1 { hi[u] } else { lo[u] };
                p[v] = if b == 1 { hi[v] } else { lo[v] };
                m.positions.push(p.to_array());
                normals.push(n.to_array());
            }
            if sign > 0.0 {
                m.triangles.push([base, base + 1, base + 2]);
                m.triangles.push([base, base + 2, base + 3]);
            } else {
                m.triangles.push([base, base + 2, base + 1]);
                m.triangles.push([base, base + 3, base + 2]);
            }
        }
    }
    m.normals = Some(normals);
    Mesh::build(m, None)
}

/// A UV sphere of `radius` mm resting on z = 0.
pub fn sphere(radius: f32, n_phi: usize, n_theta: usize) -> Result<Mesh, MeshError> {
    let mut m = MeshInput::default();
    let mut normals = Vec::new();
    for j in 0..=n_theta {
        let theta = PI * j as f32 / n_theta as f32;
        for i in 0..=n_phi {
            let phi = TAU * i as f32 / n_phi as f32;
            let n = Vec3::new(
                theta.sin() * phi.cos(),
                theta.sin() * phi.sin(),
                theta.cos(),
            );
            m.positions.push((n * radius + Vec3::Z * radius).to_array());
            normals.push(n.to_array());
        }
    }
    let row = (n_phi + 1) as u32;
    for j in 0..n_theta as u32 {
        for i in 0..n_phi as u32 {
            let (a, b) = (j * row + i, j * row + i + 1);
            let (c, d) = (a + row, b + row);
            m.triangles.push([a, c, b]);
            m.triangles.push([b, c, d]);
        }
    }
    m.normals = Some(normals);
    Mesh::build(m, None)
}

/// The Utah teapot as a closed solid, `scale` mm per teapot unit, its
/// surface on a grid of `cell` teapot units.
///
/// Newell's patches are not a solid: the spout is open at its tip, the lid
/// sits in the rim's opening without meeting it, and the handle and spout
/// end inside the body. Each hole gets a flat cap, which makes body, lid,
/// handle and spout closed shells, and their union is remeshed as one
/// watertight surface. The lips of the rim and the spout (ridges 0.1
/// units wide, thinner than the grid can draw) are left out: the lid rests
/// on a flat shoulder and the spout ends flat.
pub fn teapot(scale: f32, cell: f32) -> Result<Mesh, MeshError> {
    let mut shells = teapot_patches(&teapot_solid_patches(), scale, 16);
    cap_holes(&mut shells, 1e-4 * scale);
    Mesh::build(union_surface(&shells, cell * scale), None)
}

/// Newell's patches without the rim (the first four) and the spout's lip
/// (patches 18 and 19).
fn teapot_solid_patches() -> Vec<[u16; 16]> {
    PATCHES
        .iter()
        .enumerate()
        .filter(|(k, _)| !(*k < 4 || *k == 18 || *k == 19))
        .map(|(_, p)| *p)
        .collect()
}

/// Bezier patches of the teapot's control points, each sampled on an
/// `n` x `n` grid, `scale` mm per teapot unit, with their own normals.
pub fn teapot_patches(patches: &[[u16; 16]], scale: f32, n: usize) -> MeshInput {
    let mut m = MeshInput::default();
    let mut normals = Vec::new();
    for patch in patches {
        let cp: Vec<Vec3> = patch
            .iter()
            .map(|&i| Vec3::from(POINTS[i as usize - 1]) * scale)
            .collect();
        let base = m.positions.len() as u32;
        for i in 0..=n {
            for j in 0..=n {
                let (u, v) = (i as f32 / n as f32, j as f32 / n as f32);
                let (p, _, _) = bezier_patch(&cp, u, v);
                // A patch whose edge collapses to a point (the lid's and the
                // bottom's poles) has no derivative there: its normal is the
                // limit from just inside.
                let inside = |t: f32| t.clamp(1e-3, 1.0 - 1e-3);
                let (_, dpdu, dpdv) = bezier_patch(&cp, inside(u), inside(v));
                m.positions.push(p.to_array());
                normals.push((-dpdu.cross(dpdv)).normalize_or_zero().to_array());
            }
        }
        let row = (n + 1) as u32;
        for i in 0..n as u32 {
            for j in 0..n as u32 {
                let a = base + i * row + j;
                for t in [[a, a + 1, a + row + 1], [a, a + row + 1, a + row]] {
                    // A triangle at a pole has two corners in one place.
                    let [p, q, r] = t.map(|k| Vec3::from(m.positions[k as usize]));
                    if (q - p).cross(r - p).length_squared() > 0.0 {
                        m.triangles.push(orient(&m.positions, &normals, t));
                    }
                }
            }
        }
    }
    m.normals = Some(normals);
    m
}

/// Swaps the winding when it disagrees with the vertex normals, so face and
/// vertex normals point the same way.
fn orient(pos: &[[f32; 3]], normals: &[[f32; 3]], t: [u32; 3]) -> [u32; 3] {
    let [a, b, c] = t.map(|i| Vec3::from(pos[i as usize]));
    let ng = (b - a).cross(c - a);
    let ns: Vec3 = t.iter().map(|&i| Vec3::from(normals[i as usize])).sum();
    if ng.dot(ns) < 0.0 {
        [t[0], t[2], t[1]]
    } else {
        t
    }
}

/// Position and partial derivatives of a bicubic Bezier patch (row-major 4x4).
fn bezier_patch(cp: &[Vec3], u: f32, v: f32) -> (Vec3, Vec3, Vec3) {
    let b = |t: f32| {
        let s = 1.0 - t;
        [s * s * s, 3.0 * s * s * t, 3.0 * s * t * t, t * t * t]
    };
    let db = |t: f32| {
        let s = 1.0 - t;
        [
            -3.0 * s * s,
            3.0 * s * s - 6.0 * s * t,
            6.0 * s * t - 3.0 * t * t,
            3.0 * t * t,
        ]
    };
    let (bu, bv, dbu, dbv) = (b(u), b(v), db(u), db(v));
    let (mut p, mut du, mut dv) = (Vec3::ZERO, Vec3::ZERO, Vec3::ZERO);
    for i in 0..4 {
        for j in 0..4 {
            let c = cp[i * 4 + j];
            p += c * bu[i] * bv[j];
            du += c * dbu[i] * bv[j];
            dv += c * bu[i] * dbv[j];
        }
    }
    (p, du, dv)
}

/// The outline of a bread slice (mm, centred at the origin): a rounded
/// square loaf bottom with a wider domed crown.
fn bread_outline(n: usize) -> Vec<Vec2> {
    (0..n)
        .map(|k| {
            let t = TAU * k as f32 / n as f32;
            let (c, s) = (t.cos(), t.sin());
            // Superellipse |x/a|^4 + |y/b|^4 = 1.
            let p = 4.0;
            let r =
                (c.abs().powf(p) / 45f32.powf(p) + s.abs().powf(p) / 38f32.powf(p)).powf(-1.0 / p);
            let (mut x, mut y) = (r * c, r * s);
            // The crown bulges sideways above the tin line and is domed on top.
            let crown = ((y + 5.0) / 30.0).clamp(0.0, 1.0);
            x *= 1.0 + 0.12 * crown * crown;
            if y > 0.0 {
                y += 8.0 * (1.0 - (x / 50.0).powi(2)).max(0.0) * (y / 38.0);
                y -= 3.0 * (-(x / 9.0).powi(2)).exp() * (y / 46.0);
            }
            Vec2::new(x, y)
        })
        .collect()
}

/// A bread slice `thickness` mm thick lying flat (z from 0 to thickness),
/// its rim rounded with a radius of a third of the thickness.
pub fn bread(thickness: f32) -> Result<Mesh, MeshError> {
    let outline = bread_outline(160);
    let n = outline.len();
    let rho = thickness / 3.0;
    let half = thickness / 2.0;
    // Outward unit normals of the outline (central differences).
    let normals_xy: Vec<Vec2> = (0..n)
        .map(|i| {
            let d = outline[(i + 1) % n] - outline[(i + n - 1) % n];
            Vec2::new(d.y, -d.x).normalize()
        })
        .collect();
    // Rings from the bottom centre to the top centre: (inset, scale, z).
    let mut rings: Vec<(f32, f32, f32)> = Vec::new();
    let caps = 6;
    for k in 0..=caps {
        rings.push((rho, k as f32 / caps as f32, -half));
    }
    let arc = 6;
    for k in 1..=arc {
        let phi = -PI / 2.0 + PI / 2.0 * k as f32 / arc as f32;
        rings.push((
            rho * (1.0 - phi.cos()),
            1.0,
            -(half - rho) + rho * phi.sin(),
        ));
    }
    for k in 0..=arc {
        let phi = PI / 2.0 * k as f32 / arc as f32;
        rings.push((rho * (1.0 - phi.cos()), 1.0, half - rho + rho * phi.sin()));
    }
    for k in (0..caps).rev() {
        rings.push((rho, k as f32 / caps as f32, half));
    }
    let mut m = MeshInput::default();
    for &(inset, s, z) in &rings {
        for i in 0..n {
            let p = (outline[i] - normals_xy[i] * inset) * s;
            m.positions.push([p.x, p.y, z + half]);
        }
    }
    let nn = n as u32;
    for j in 0..rings.len() as u32 - 1 {
        for i in 0..nn {
            let (a, b) = (j * nn + i, j * nn + (i + 1) % nn);
            let (c, d) = (a + nn, b + nn);
            m.triangles.push([a, b, d]);
            m.triangles.push([a, d, c]);
        }
    }
    Mesh::build(m, None)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slab_is_a_closed_box() {
        let m = slab(10.0, 2.0).unwrap();
        assert_eq!(m.triangles.len(), 12);
        assert!((m.total_area() - (2.0 * 100.0 + 4.0 * 20.0)).abs() < 1e-3);
    }

    #[test]
    fn sphere_area_matches() {
        let m = sphere(10.0, 128, 64).unwrap();
        let exact = 4.0 * PI * 100.0;
        assert!((m.total_area() - exact).abs() / exact < 0.01);
    }

    #[test]
    fn teapot_has_the_classic_size() {
        let cell = 0.05;
        let m = teapot(1.0, cell).unwrap();
        let (lo, hi) = m.bounds();
        // Spout's end at x = 3.3 (without its lip), handle at x = -3, lid
        // knob at z = 3.15.
        assert!((hi.x - 3.3).abs() < cell, "{hi}");
        assert!((lo.x + 3.0).abs() < cell, "{lo}");
        assert!((hi.z - 3.15).abs() < cell && lo.z.abs() < cell, "{lo} {hi}");
    }

    #[test]
    fn teapot_is_one_closed_solid() {
        use crate::watertight::tests::{is_closed, volume};
        // A mesh with its coincident vertices joined.
        let welded = |m: &Mesh| MeshInput {
            positions: m.positions.iter().map(|p| p.to_array()).collect(),
            triangles: m
                .triangles
                .iter()
                .map(|t| t.map(|i| m.weld[i as usize]))
                .collect(),
            ..Default::default()
        };
        let m = welded(&teapot(12.0, TEAPOT_CELL).unwrap());
        assert!(
            is_closed(&m),
            "edges not shared by exactly two faces, once each way"
        );
        // The patches alone leave the spout, the rim and the handle's and
        // spout's ends open: the check can fail.
        let patches = Mesh::build(teapot_patches(&PATCHES, 12.0, 16), None).unwrap();
        assert!(!is_closed(&welded(&patches)));
        // The union encloses less than the capped shells summed (the handle's
        // and spout's ends inside the body count once), but not much less.
        let mut shells = teapot_patches(&teapot_solid_patches(), 12.0, 16);
        cap_holes(&mut shells, 1e-3);
        let (union, summed) = (volume(&m), volume(&shells));
        eprintln!(
            "teapot: {} triangles, {union} mm^3 against {summed} summed",
            m.triangles.len()
        );
        assert!(union < 0.998 * summed && union > 0.95 * summed);
    }

    #[test]
    fn bread_is_watertight_and_sized() {
        let m = bread(12.0).unwrap();
        let (lo, hi) = m.bounds();
        assert!((hi.z - lo.z - 12.0).abs() < 1e-3);
        assert!(hi.x - lo.x > 80.0 && hi.x - lo.x < 120.0);
        assert!(m.total_area() > 2.0 * 5000.0);
    }
}
