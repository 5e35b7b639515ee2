//! Triangle meshes: loading (OBJ via [`crate::obj`], PLY via [`crate::ply`]),
//! validation (finite values, indices, manifold edges, degenerate faces),
//! and the attributes the renderer needs: per-vertex normals (generated from
//! area-weighted face normals when absent, split at creases) and per-corner surface texture
//! coordinates in millimetres (box-projected when absent).

use std::collections::HashMap;
use std::path::Path;

use glam::{Vec2, Vec3};

use crate::error::MeshError;
use crate::mesh_input::MeshInput;

/// A validated triangle mesh in millimetres.
#[derive(Clone, Debug)]
pub struct Mesh {
    pub positions: Vec<Vec3>,
    /// Per-vertex unit normals; a zero vector means "use the face normal".
    pub normals: Vec<Vec3>,
    pub triangles: Vec<[u32; 3]>,
    /// Per-triangle-corner texture coordinates, in mm along the surface.
    pub uvs: Vec<[Vec2; 3]>,
    /// For each vertex, the first vertex at its position (itself if none
    /// came before): joins split copies at UV seams, patch borders, creases.
    pub weld: Vec<u32>,
    /// Faces dropped at load because their area was zero.
    pub dropped_degenerate: usize,
}

/// The smallest and largest object a mesh may be, across its bounding box,
/// in mm: beyond them f32 geometry loses its faces (to overflow at 1e30 mm)
/// and no material measured in mm makes sense.
pub const MIN_EXTENT_MM: f64 = 1e-3;
pub const MAX_EXTENT_MM: f64 = 1e7;

/// Diagonal of the bounding box of the finite points; None when there are
/// none or they coincide (such a mesh has no faces, which `build` says).
fn extent(points: impl Iterator<Item = [f32; 3]>) -> Option<f64> {
    let (lo, hi) = points.filter(|p| p.iter().all(|c| c.is_finite())).fold(
        None,
        |b: Option<([f64; 3], [f64; 3])>, p| {
            let p = p.map(f64::from);
            Some(b.map_or((p, p), |(lo, hi)| {
                (
                    [lo[0].min(p[0]), lo[1].min(p[1]), lo[2].min(p[2])],
                    [hi[0].max(p[0]), hi[1].max(p[1]), hi[2].max(p[2])],
                )
            }))
        },
    )?;
    let d = (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f64>().sqrt();
    (d > 0.0).then_some(d)
}

/// Refuses a scale that is not a positive number or that puts an object of
/// `extent` file units outside [MIN_EXTENT_MM, MAX_EXTENT_MM].
fn check_scale(extent: Option<f64>, scale: f32) -> Result<(), MeshError> {
    // 1e30 as the user wrote it, not 31 digits.
    let scale_text = if scale != 0.0 && !(1e-4..1e9).contains(&scale.abs()) {
        format!("{scale:e}")
    } else {
        scale.to_string()
    };
    let scale_text = scale_text.as_str();
    if !(scale.is_finite() && scale > 0.0) {
        return Err(MeshError::Scale(format!(
            "mesh scale {scale_text} (object.scale) must be a number > 0"
        )));
    }
    match extent.map(|e| e * f64::from(scale)) {
        Some(mm) if !(MIN_EXTENT_MM..=MAX_EXTENT_MM).contains(&mm) => {
            Err(MeshError::Scale(format!(
                "mesh scale {scale_text} (object.scale) is out of range: it makes the object \
                 {mm:.3e} mm across, and it must be {MIN_EXTENT_MM} to {MAX_EXTENT_MM} mm"
            )))
        }
        _ => Ok(()),
    }
}

impl Mesh {
    /// Loads an OBJ or PLY file (by extension), positions in file units.
    pub fn load_input(path: &Path) -> Result<MeshInput, MeshError> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(|e| e.to_ascii_lowercase());
        if !path.exists() {
            return Err(MeshError::Io {
                path: path.to_path_buf(),
                source: std::io::Error::new(std::io::ErrorKind::NotFound, "no such file"),
            });
        }
        if path.is_dir() {
            return Err(MeshError::Io {
                path: path.to_path_buf(),
                source: std::io::Error::new(std::io::ErrorKind::IsADirectory, "it is a directory"),
            });
        }
        match ext.as_deref() {
            Some("obj") => crate::obj::read(path),
            Some("ply") => {
                let bytes = std::fs::read(path).map_err(|source| MeshError::Io {
                    path: path.to_path_buf(),
                    source,
                })?;
                crate::ply::parse(&bytes)
            }
            _ => Err(MeshError::UnsupportedFormat(path.to_path_buf())),
        }
    }

    /// Loads and validates a mesh file; `scale` converts file units to mm and
    /// `uv_scale_mm` is the surface length one file UV unit spans.
    pub fn load(path: &Path, scale: f32, uv_scale_mm: Option<f32>) -> Result<Mesh, MeshError> {
        let mut input = Self::load_input(path)?;
        check_scale(extent(input.positions.iter().copied()), scale)?;
        input.scale(scale);
        Mesh::build(input, uv_scale_mm)
    }

    /// This mesh `scale` times larger, as if built from scaled positions
    /// (welding and the degenerate-face test are relative to its size, and
    /// its surface coordinates are in mm, so they scale too).
    pub fn scaled(mut self, scale: f32) -> Result<Mesh, MeshError> {
        check_scale(extent(self.positions.iter().map(|p| p.to_array())), scale)?;
        if scale != 1.0 {
            for p in &mut self.positions {
                *p *= scale;
            }
            for uv in self.uvs.iter_mut().flatten() {
                *uv *= scale;
            }
        }
        Ok(self)
    }

    /// Validates raw data and derives normals and UVs.
    /// `uv_scale_mm`: mm per file UV unit; `None` means the bounding-box
    /// diagonal (one UV unit spans the object).
    pub fn build(input: MeshInput, uv_scale_mm: Option<f32>) -> Result<Mesh, MeshError> {
        let MeshInput {
            positions,
            normals,
            uvs,
            triangles,
        } = input;
        let n = positions.len();
        for (i, p) in positions.iter().enumerate() {
            if !p.iter().all(|c| c.is_finite()) {
                return Err(MeshError::NonFinite {
                    what: "vertex",
                    index: i,
                });
            }
        }
        if let Some(ns) = &normals {
            if ns.len() != n {
                return Err(MeshError::AttributeCount {
                    what: "normal",
                    got: ns.len(),
                    expected: n,
                });
            }
            if let Some(i) = ns.iter().position(|v| !v.iter().all(|c| c.is_finite())) {
                return Err(MeshError::NonFinite {
                    what: "normal",
                    index: i,
                });
            }
        }
        if let Some(us) = &uvs {
            if us.len() != n {
                return Err(MeshError::AttributeCount {
                    what: "uv",
                    got: us.len(),
                    expected: n,
                });
            }
            if let Some(i) = us.iter().position(|v| !v.iter().all(|c| c.is_finite())) {
                return Err(MeshError::NonFinite {
                    what: "uv",
                    index: i,
                });
            }
        }
        for (f, t) in triangles.iter().enumerate() {
            for &i in t {
                if i as usize >= n {
                    return Err(MeshError::IndexOutOfRange {
                        face: f,
                        index: i,
                        count: n,
                    });
                }
            }
        }
        let positions: Vec<Vec3> = positions.iter().map(|p| Vec3::from(*p)).collect();

        // Weld coincident positions (split vertices at UV seams, poles) so
        // topology and generated normals see one vertex.
        let (lo, hi) = bounds(&positions);
        let diag = (hi - lo).length().max(f32::MIN_POSITIVE);
        let weld = weld_ids(&positions, diag * 1e-6);

        // Drop faces of zero area (relative to the mesh size) or with two
        // corners welded together.
        let min_area = (diag * 1e-7).powi(2);
        let mut kept = Vec::with_capacity(triangles.len());
        let mut degenerate = 0;
        for t in &triangles {
            let [a, b, c] = t.map(|i| positions[i as usize]);
            let [wa, wb, wc] = t.map(|i| weld[i as usize]);
            if 0.5 * (b - a).cross(c - a).length() > min_area && wa != wb && wb != wc && wa != wc {
                kept.push(*t);
            } else {
                degenerate += 1;
            }
        }
        if kept.is_empty() {
            return Err(MeshError::NoFaces { degenerate });
        }
        let triangles = kept;
        check_manifold(&triangles, &weld, &positions)?;

        // Texture coordinates first: generated normals may split vertices.
        let uvs: Vec<[Vec2; 3]> = match uvs {
            Some(us) => {
                let s = uv_scale_mm.unwrap_or(diag);
                triangles
                    .iter()
                    .map(|t| t.map(|i| Vec2::from(us[i as usize]) * s))
                    .collect()
            }
            None => triangles
                .iter()
                .map(|t| box_projection(t.map(|i| positions[i as usize])))
                .collect(),
        };
        let (mut positions, mut triangles, mut weld) = (positions, triangles, weld);
        let normals = match normals {
            Some(ns) => ns
                .iter()
                .map(|v| Vec3::from(*v).normalize_or_zero())
                .collect(),
            None => generated_normals(&mut positions, &mut triangles, &mut weld),
        };
        Ok(Mesh {
            positions,
            normals,
            triangles,
            uvs,
            weld,
            dropped_degenerate: degenerate,
        })
    }

    /// The three corners of triangle `t`.
    pub fn corners(&self, t: usize) -> [Vec3; 3] {
        self.triangles[t].map(|i| self.positions[i as usize])
    }

    /// Area of triangle `t`, mm^2.
    pub fn area(&self, t: usize) -> f32 {
        let [a, b, c] = self.corners(t);
        0.5 * (b - a).cross(c - a).length()
    }

    /// Total surface area, mm^2.
    pub fn total_area(&self) -> f32 {
        (0..self.triangles.len()).map(|t| self.area(t)).sum()
    }

    /// Axis-aligned bounds of all vertices.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        bounds(&self.positions)
    }

    /// Unit geometric normal of triangle `t` (winding order).
    pub fn face_normal(&self, t: usize) -> Vec3 {
        let [a, b, c] = self.corners(t);
        (b - a).cross(c - a).normalize_or_zero()
    }

    /// Interpolated shading normal at barycentrics (b1, b2); falls back to the
    /// face normal where vertex normals vanish or cancel.
    pub fn shading_normal(&self, t: usize, b1: f32, b2: f32) -> Vec3 {
        let [i0, i1, i2] = self.triangles[t].map(|i| i as usize);
        let n = self.normals[i0] * (1.0 - b1 - b2) + self.normals[i1] * b1 + self.normals[i2] * b2;
        let ng = self.face_normal(t);
        match n.try_normalize() {
            // Keep the interpolated normal on the same side as the face normal.
            Some(n) if n.dot(ng).abs() > 1e-3 => {
                if n.dot(ng) < 0.0 {
                    -n
                } else {
                    n
                }
            }
            _ => ng,
        }
    }

    /// Which side of the winding the outside lies on: +1 (normals point
    /// out) or -1 for a closed mesh, every edge (of welded vertices) in
    /// exactly two faces, once each way, whose shells all enclose their
    /// volume the same way round; None otherwise (an open surface, or shells
    /// wound differently, as a hollow part's inner wall is), and light may
    /// reach the surface from either side. From inside a closed surface
    /// every ray meets it again, so light arrives from outside only.
    pub fn outside(&self) -> Option<f32> {
        let mut directed: HashMap<(u32, u32), u32> =
            HashMap::with_capacity(3 * self.triangles.len());
        for t in &self.triangles {
            let w = t.map(|i| self.weld[i as usize]);
            for k in 0..3 {
                *directed.entry((w[k], w[(k + 1) % 3])).or_default() += 1;
            }
        }
        let closed = directed
            .iter()
            .all(|(&(a, b), &c)| c == 1 && directed.get(&(b, a)) == Some(&1));
        if !closed {
            return None;
        }
        // Shells: faces joined through their welded corners.
        let mut shells = DisjointSets::new(self.positions.len());
        for t in &self.triangles {
            let w = t.map(|i| self.weld[i as usize]);
            shells.join(w[0], w[1]);
            shells.join(w[0], w[2]);
        }
        // Six times each shell's enclosed volume, signed by the winding.
        let mut volume: HashMap<u32, f64> = HashMap::new();
        for (t, tri) in self.triangles.iter().enumerate() {
            let [a, b, c] = self.corners(t).map(|p| p.as_dvec3());
            let shell = shells.root(self.weld[tri[0] as usize]);
            *volume.entry(shell).or_default() += a.dot(b.cross(c));
        }
        let sign = volume.values().next()?.signum();
        volume
            .values()
            .all(|v| *v != 0.0 && v.signum() == sign)
            .then_some(sign as f32)
    }

    /// Barycentrics (b1, b2) of the point of triangle `t`'s plane nearest
    /// to `p`.
    pub fn barycentric(&self, t: usize, p: Vec3) -> (f32, f32) {
        let [a, b, c] = self.corners(t);
        let (e1, e2, d) = (b - a, c - a, p - a);
        let (d11, d12, d22) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
        let (d1, d2) = (d.dot(e1), d.dot(e2));
        let det = d11 * d22 - d12 * d12;
        if det.abs() <= f32::MIN_POSITIVE {
            return (1.0 / 3.0, 1.0 / 3.0);
        }
        ((d22 * d1 - d12 * d2) / det, (d11 * d2 - d12 * d1) / det)
    }

    /// Surface texture coordinate (mm) at barycentrics (b1, b2).
    pub fn uv(&self, t: usize, b1: f32, b2: f32) -> Vec2 {
        let [a, b, c] = self.uvs[t];
        a * (1.0 - b1 - b2) + b * b1 + c * b2
    }
}

/// Axis-aligned bounds of a point set.
pub fn bounds(points: &[Vec3]) -> (Vec3, Vec3) {
    points.iter().fold(
        (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
        |(lo, hi), p| (lo.min(*p), hi.max(*p)),
    )
}

/// Maps each vertex to the id of the first vertex within `tol` (grid hash).
/// Disjoint sets of 0..n (union-find with path halving). A join keeps the
/// smaller root, so the sets' roots do not depend on the order of joins
/// within a set.
pub(crate) struct DisjointSets(Vec<u32>);

impl DisjointSets {
    pub(crate) fn new(n: usize) -> DisjointSets {
        DisjointSets((0..n as u32).collect())
    }

    pub(crate) fn root(&mut self, mut i: u32) -> u32 {
        let p = &mut self.0;
        while p[i as usize] != i {
            p[i as usize] = p[p[i as usize] as usize];
            i = p[i as usize];
        }
        i
    }

    pub(crate) fn join(&mut self, a: u32, b: u32) {
        let (ra, rb) = (self.root(a), self.root(b));
        self.0[ra.max(rb) as usize] = ra.min(rb);
    }
}

pub(crate) fn weld_ids(positions: &[Vec3], tol: f32) -> Vec<u32> {
    let inv = 1.0 / tol.max(f32::MIN_POSITIVE);
    let mut map: HashMap<[i64; 3], u32> = HashMap::with_capacity(positions.len());
    positions
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let key = [
                (p.x * inv).round() as i64,
                (p.y * inv).round() as i64,
                (p.z * inv).round() as i64,
            ];
            *map.entry(key).or_insert(i as u32)
        })
        .collect()
}

fn check_manifold(triangles: &[[u32; 3]], weld: &[u32], pos: &[Vec3]) -> Result<(), MeshError> {
    let mut edges: HashMap<(u32, u32), u32> = HashMap::with_capacity(triangles.len() * 3);
    for t in triangles {
        let w = t.map(|i| weld[i as usize]);
        for k in 0..3 {
            let (a, b) = (w[k], w[(k + 1) % 3]);
            if a == b {
                continue;
            }
            *edges.entry((a.min(b), a.max(b))).or_default() += 1;
        }
    }
    let bad: Vec<_> = edges.iter().filter(|(_, c)| **c > 2).collect();
    if let Some(((a, _), _)) = bad.first() {
        return Err(MeshError::NonManifold {
            edges: bad.len(),
            at: pos[*a as usize].to_array(),
        });
    }
    Ok(())
}

/// Neighbouring faces meeting at more than this angle (degrees) keep their
/// own normals when normals are generated: a box's faces stay flat, while
/// a sphere of 16 segments (22.5 degrees between neighbours) stays smooth.
pub const CREASE_DEG: f32 = 30.0;

/// Per-vertex normals for a mesh that has none. The faces around a vertex
/// fall into smoothing groups: two faces that share an edge there join when
/// they meet at less than [`CREASE_DEG`]. Each corner takes the
/// area-weighted normal of its face's group. A vertex with more than one
/// group (on a crease, a box's corner) is split into copies, appended to
/// `positions` and `weld` (a copy welds to what its original welds to),
/// and the triangles index the copies.
fn generated_normals(
    positions: &mut Vec<Vec3>,
    triangles: &mut [[u32; 3]],
    weld: &mut Vec<u32>,
) -> Vec<Vec3> {
    // Cross product length = 2 * area: area weighting for free.
    let area_normals: Vec<Vec3> = triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| positions[i as usize]);
            (b - a).cross(c - a)
        })
        .collect();
    let unit: Vec<Vec3> = area_normals.iter().map(|n| n.normalize_or_zero()).collect();
    let welded = |f: usize| triangles[f].map(|i| weld[i as usize]);
    let mut around: HashMap<u32, Vec<usize>> = HashMap::new();
    for f in 0..triangles.len() {
        for w in welded(f) {
            around.entry(w).or_default().push(f);
        }
    }
    let cos_crease = CREASE_DEG.to_radians().cos();
    // The normal of each face's group around each of its welded corners.
    let mut corner_normal: HashMap<(usize, u32), Vec3> = HashMap::new();
    for (&w, faces) in &around {
        // the fan's faces, joined across smooth edges through w
        let mut groups = DisjointSets::new(faces.len());
        for a in 0..faces.len() {
            for b in a + 1..faces.len() {
                let (fa, fb) = (faces[a], faces[b]);
                let (va, vb) = (welded(fa), welded(fb));
                let shares_edge = va.iter().any(|&x| x != w && vb.contains(&x));
                if shares_edge && unit[fa].dot(unit[fb]) >= cos_crease {
                    groups.join(a as u32, b as u32);
                }
            }
        }
        let mut sums: HashMap<u32, Vec3> = HashMap::new();
        for (a, &f) in faces.iter().enumerate() {
            *sums.entry(groups.root(a as u32)).or_default() += area_normals[f];
        }
        for (a, &f) in faces.iter().enumerate() {
            let n = sums[&groups.root(a as u32)].normalize_or_zero();
            corner_normal.insert((f, w), n);
        }
    }
    let mut normals = vec![Vec3::ZERO; positions.len()];
    // The normals each original vertex has been given, with the vertex
    // (itself or a copy) that carries each.
    let mut given: Vec<Vec<(Vec3, u32)>> = vec![Vec::new(); positions.len()];
    for f in 0..triangles.len() {
        for k in 0..3 {
            let i = triangles[f][k] as usize;
            let n = corner_normal[&(f, weld[i])];
            let carrier = match given[i].iter().find(|(m, _)| m.dot(n) > 0.9999) {
                Some(&(_, v)) => v,
                None if given[i].is_empty() => {
                    normals[i] = n;
                    given[i].push((n, i as u32));
                    i as u32
                }
                None => {
                    let v = positions.len() as u32;
                    positions.push(positions[i]);
                    weld.push(weld[i]);
                    normals.push(n);
                    given[i].push((n, v));
                    v
                }
            };
            triangles[f][k] = carrier;
        }
    }
    normals
}

/// Box projection: drop the face normal's dominant axis, keep the other two
/// coordinates as the texture coordinate (mm).
fn box_projection(p: [Vec3; 3]) -> [Vec2; 3] {
    let n = (p[1] - p[0]).cross(p[2] - p[0]).abs();
    p.map(|q| {
        if n.z >= n.x && n.z >= n.y {
            Vec2::new(q.x, q.y)
        } else if n.x >= n.y {
            Vec2::new(q.y, q.z)
        } else {
            Vec2::new(q.x, q.z)
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn quad() -> MeshInput {
        MeshInput {
            positions: vec![[0., 0., 0.], [1., 0., 0.], [1., 1., 0.], [0., 1., 0.]],
            triangles: vec![[0, 1, 2], [0, 2, 3]],
            ..Default::default()
        }
    }

    #[test]
    fn quad_gets_normals_and_uvs() {
        let m = Mesh::build(quad(), None).unwrap();
        assert_eq!(m.normals[0], Vec3::Z);
        assert!((m.total_area() - 1.0).abs() < 1e-6);
        assert_eq!(m.uv(0, 1.0, 0.0), Vec2::new(1.0, 0.0));
        let (b1, b2) = m.barycentric(0, Vec3::new(0.75, 0.25, 0.3));
        assert!(
            (b1 - 0.5).abs() < 1e-6 && (b2 - 0.25).abs() < 1e-6,
            "{b1} {b2}"
        );
    }

    /// A box of 8 shared corners, as a hand-written OBJ without normals has.
    fn shared_corner_box() -> MeshInput {
        let positions = (0..8)
            .map(|i| [(i & 1) as f32, ((i >> 1) & 1) as f32, ((i >> 2) & 1) as f32])
            .collect();
        let quads = [
            [0, 2, 3, 1],
            [4, 5, 7, 6],
            [0, 1, 5, 4],
            [2, 6, 7, 3],
            [0, 4, 6, 2],
            [1, 3, 7, 5],
        ];
        MeshInput {
            positions,
            triangles: quads
                .iter()
                .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
                .collect(),
            ..Default::default()
        }
    }

    #[test]
    fn generated_normals_keep_a_box_flat_and_a_sphere_smooth() {
        let m = Mesh::build(shared_corner_box(), None).unwrap();
        // every corner of every face carries the face's own normal
        for t in 0..m.triangles.len() {
            let face = m.face_normal(t);
            for (b1, b2) in [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (0.3, 0.3)] {
                let n = m.shading_normal(t, b1, b2);
                assert!((n - face).length() < 1e-6, "face {t}: {n} against {face}");
            }
        }
        // 8 corners, each on 3 faces; the copies weld to their originals
        assert_eq!(m.positions.len(), 24);
        assert_eq!(
            m.weld
                .iter()
                .collect::<std::collections::HashSet<_>>()
                .len(),
            8
        );
        // a sphere of 16 x 8 facets has no crease: no vertex is split
        let s = crate::builtin::sphere(10.0, 16, 8).unwrap();
        let input = MeshInput {
            positions: s.positions.iter().map(|p| p.to_array()).collect(),
            triangles: s.triangles.clone(),
            ..Default::default()
        };
        let welded = input.positions.len();
        let g = Mesh::build(input, None).unwrap();
        assert_eq!(g.positions.len(), welded);
        // (the sphere rests on z = 0)
        for &i in g.triangles.iter().flatten() {
            let (p, n) = (g.positions[i as usize], g.normals[i as usize]);
            assert!(n.dot((p - Vec3::Z * 10.0).normalize()) > 0.95, "{n} at {p}");
        }
    }

    #[test]
    fn closed_meshes_know_their_outside() {
        // Split corners (a box's faces, the teapot's creases) weld shut.
        assert_eq!(
            Mesh::build(shared_corner_box(), None).unwrap().outside(),
            Some(1.0)
        );
        for m in [
            crate::builtin::sphere(10.0, 16, 8).unwrap(),
            crate::builtin::slab(60.0, 10.0).unwrap(),
            crate::builtin::teapot(12.0, crate::builtin::TEAPOT_CELL).unwrap(),
        ] {
            assert_eq!(m.outside(), Some(1.0));
        }
        // Wound inside out, the outside is against the normals.
        let mut inverted = shared_corner_box();
        inverted.triangles.iter_mut().for_each(|t| t.swap(1, 2));
        assert_eq!(Mesh::build(inverted, None).unwrap().outside(), Some(-1.0));
        // A box without its lid, a lone quad, a face wound against its
        // neighbours: light reaches both sides.
        let mut open = shared_corner_box();
        open.triangles.truncate(10);
        let mut flipped = shared_corner_box();
        flipped.triangles[0].swap(1, 2);
        flipped.triangles[1].swap(1, 2);
        for m in [open, quad(), flipped] {
            assert_eq!(Mesh::build(m, None).unwrap().outside(), None);
        }
        // Two boxes apart: both wound outwards, or one inside out.
        let two = |invert: bool| {
            let mut m = shared_corner_box();
            let mut other = shared_corner_box();
            for p in &mut other.positions {
                p[0] += 3.0;
            }
            if invert {
                other.triangles.iter_mut().for_each(|t| t.swap(1, 2));
            }
            let base = m.positions.len() as u32;
            m.positions.extend(other.positions);
            m.triangles
                .extend(other.triangles.iter().map(|t| t.map(|i| i + base)));
            Mesh::build(m, None).unwrap().outside()
        };
        assert_eq!(two(false), Some(1.0));
        assert_eq!(two(true), None);
    }

    #[test]
    fn nan_vertex_is_an_error() {
        let mut q = quad();
        q.positions[2][1] = f32::NAN;
        assert!(matches!(
            Mesh::build(q, None),
            Err(MeshError::NonFinite { index: 2, .. })
        ));
    }

    #[test]
    fn bad_index_is_an_error() {
        let mut q = quad();
        q.triangles[1][2] = 9;
        assert!(matches!(
            Mesh::build(q, None),
            Err(MeshError::IndexOutOfRange { index: 9, .. })
        ));
    }

    #[test]
    fn only_degenerate_faces_is_an_error() {
        let q = MeshInput {
            positions: vec![[0., 0., 0.], [1., 0., 0.], [2., 0., 0.]],
            triangles: vec![[0, 1, 2]],
            ..Default::default()
        };
        assert!(matches!(
            Mesh::build(q, None),
            Err(MeshError::NoFaces { degenerate: 1 })
        ));
    }

    #[test]
    fn three_faces_on_one_edge_is_non_manifold() {
        let q = MeshInput {
            positions: vec![
                [0., 0., 0.],
                [1., 0., 0.],
                [0., 1., 0.],
                [0., -1., 0.],
                [0., 0., 1.],
            ],
            triangles: vec![[0, 1, 2], [0, 1, 3], [0, 1, 4]],
            ..Default::default()
        };
        assert!(matches!(
            Mesh::build(q, None),
            Err(MeshError::NonManifold { edges: 1, .. })
        ));
    }

    #[test]
    fn obj_file_loads_with_uvs_scaled() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("q.obj");
        std::fs::write(
            &p,
            "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nf 1/1 2/2 3/3 4/4\n",
        )
        .unwrap();
        let m = Mesh::load(&p, 10.0, Some(20.0)).unwrap();
        assert_eq!(m.triangles.len(), 2);
        assert!((m.total_area() - 100.0).abs() < 1e-3);
        // One file UV unit spans 20 mm of surface.
        let uv = m.uvs.iter().flatten().fold(Vec2::ZERO, |a, b| a.max(*b));
        assert_eq!(uv, Vec2::new(20.0, 20.0));
        let bad = dir.path().join("q.stl");
        std::fs::write(&bad, "solid").unwrap();
        assert!(matches!(
            Mesh::load(&bad, 1.0, None),
            Err(MeshError::UnsupportedFormat(_))
        ));
        let empty = dir.path().join("e.obj");
        std::fs::write(&empty, "v 0 0 0\n").unwrap();
        assert!(Mesh::load(&empty, 1.0, None).is_err());
    }

    #[test]
    fn scales_that_put_the_mesh_out_of_range_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("q.obj");
        std::fs::write(&p, "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n").unwrap();
        for s in [1e30, 1e8, 1e-4, 0.0, -1.0, f32::NAN] {
            let e = Mesh::load(&p, s, None).unwrap_err().to_string();
            let written = if s == 1e30 {
                "1e30".to_string()
            } else {
                s.to_string()
            };
            assert!(e.contains(&format!("scale {written} ")), "{s}: {e}");
            let range = s > 0.0 && s.is_finite();
            assert_eq!(e.contains("0.001 to 10000000 mm"), range, "{s}: {e}");
            assert!(!e.contains("degenerate"), "{s}: {e}");
        }
        assert!(Mesh::load(&p, 1e6, None).is_ok());
        let m = Mesh::build(quad(), None).unwrap();
        let big = m.clone().scaled(3.0).unwrap();
        assert!((big.total_area() - 9.0 * m.total_area()).abs() < 1e-4);
        assert_eq!(big.uv(0, 1.0, 0.0), 3.0 * m.uv(0, 1.0, 0.0));
        assert!(m.scaled(1e30).is_err());
    }

    #[test]
    fn missing_file_is_an_error() {
        let e = Mesh::load(Path::new("/nonexistent/x.obj"), 1.0, None).unwrap_err();
        assert!(e.to_string().contains("cannot read mesh"));
    }
}
