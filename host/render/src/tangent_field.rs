//! A smooth tangent field on a mesh: one tangent per vertex that turns as
//! little as the surface allows from vertex to vertex. It orients the
//! material texture on the surface (the texture's +u axis, and so the
//! azimuth of every f, f_v and LRF lookup), so a frame that jumped between
//! neighbouring vertices would show as a crease.
//!
//! Method: Knöppel, Crane, Pinkall & Schröder 2013, "Globally optimal
//! direction fields". A tangent is a complex number in a per-vertex basis;
//! parallel transport along an edge is a rotation e^{iρ}. The field
//! minimises the cotangent-weighted connection Dirichlet energy
//! Σ_edges w |z_i - e^{iρ_ij} z_j|² plus a pull s |z - q|² towards a guide q
//! (the up direction projected on the surface), one sparse Hermitian solve
//! (L + s M) z = s M q by conjugate gradients per connected part. Where the
//! guide fades (a pole) smoothness decides, and the singularities a closed
//! surface must have land there.
//!
//! Coincident vertices (UV seams, patch borders) are joined by stiff edges
//! so the field is continuous across them; across a sharp crease (a box's
//! edge) they are not, and each face keeps its own guide.

use glam::{DVec2, Quat, Vec3};
use rayon::prelude::*;

use crate::mesh::{DisjointSets, Mesh};

/// One tangent per mesh vertex. Its length is the field's strength (about 1
/// on average, falling to 0 at a singularity); only the direction orients
/// the texture.
#[derive(Clone, Debug, Default)]
pub struct TangentField {
    pub tangents: Vec<Vec3>,
}

/// An edge of the field's graph: a mesh edge, or a link between two
/// vertices at one position.
#[derive(Clone, Copy, Debug)]
struct Link {
    a: u32,
    b: u32,
    /// Transport from b's basis to a's: z in b's basis is e^{iρ} z in a's.
    rot: DVec2,
    /// Cotangent weight of a mesh edge; a stiff weight for a weld.
    w: f64,
}

/// The length over which the field prefers smoothness to the guide, as a
/// share of the object's bounding-box diagonal.
const SMOOTHING: f32 = 0.2;

/// A connected part whose mean tilt (the sine of its normal's angle to
/// +z) is below this is level: +z projects to almost nothing on it, so
/// the field follows +x there.
const LEVEL_TILT: f64 = 0.1;

/// Complex product.
fn mul(a: DVec2, b: DVec2) -> DVec2 {
    DVec2::new(a.x * b.x - a.y * b.y, a.x * b.y + a.y * b.x)
}

fn conj(a: DVec2) -> DVec2 {
    DVec2::new(a.x, -a.y)
}

/// Per-vertex unit normals: the mesh's, or the mean of the faces around a
/// vertex where the mesh has none.
fn vertex_normals(mesh: &Mesh) -> Vec<Vec3> {
    let mut faces = vec![Vec3::ZERO; mesh.positions.len()];
    for (t, tri) in mesh.triangles.iter().enumerate() {
        let n = mesh.face_normal(t);
        for &i in tri {
            faces[i as usize] += n;
        }
    }
    mesh.normals
        .iter()
        .zip(faces)
        .map(|(n, f)| n.try_normalize().or(f.try_normalize()).unwrap_or(Vec3::Z))
        .collect()
}

/// A basis (e1, e2) of the tangent plane of every vertex.
fn bases(normals: &[Vec3]) -> Vec<(Vec3, Vec3)> {
    normals
        .iter()
        .map(|n| {
            let e1 = n.any_orthonormal_vector();
            (e1, n.cross(e1))
        })
        .collect()
}

/// The rotation taking b's basis into a's along the minimal rotation of
/// b's normal onto a's.
fn transport(na: Vec3, ba: (Vec3, Vec3), nb: Vec3, bb: (Vec3, Vec3)) -> DVec2 {
    let v = Quat::from_rotation_arc(nb, na) * bb.0;
    DVec2::new(v.dot(ba.0) as f64, v.dot(ba.1) as f64).normalize_or(DVec2::X)
}

/// The graph's edges: every mesh edge once with its cotangent weight (so
/// the field is smooth over the surface, not over the mesh's density), and
/// a stiff link from each welded copy of a vertex to the copy it was welded
/// to.
fn links(mesh: &Mesh, normals: &[Vec3], basis: &[(Vec3, Vec3)]) -> Vec<Link> {
    let mut weights: std::collections::HashMap<(u32, u32), f64> = Default::default();
    for tri in &mesh.triangles {
        let p = tri.map(|i| mesh.positions[i as usize].as_dvec3());
        for k in 0..3 {
            let (a, b, o) = (k, (k + 1) % 3, (k + 2) % 3);
            let (u, v) = (p[a] - p[o], p[b] - p[o]);
            let cot = u.dot(v) / u.cross(v).length().max(1e-300);
            let key = (tri[a].min(tri[b]), tri[a].max(tri[b]));
            *weights.entry(key).or_default() += 0.5 * cot;
        }
    }
    // In key order: a sum over the map's own (per-process random) order
    // differs in its last bits from run to run, and so would every render.
    let mut weights: Vec<((u32, u32), f64)> = weights.into_iter().collect();
    weights.sort_unstable_by_key(|w| w.0);
    // Obtuse triangles can make a cotangent weight negative; a small floor
    // keeps the operator definite.
    let mean = weights.iter().map(|w| w.1.abs()).sum::<f64>() / weights.len().max(1) as f64;
    let floor = 1e-3 * mean.max(f64::MIN_POSITIVE);
    let stiff = 10.0 * mean.max(f64::MIN_POSITIVE);
    // Welded copies whose normals differ by more than a crease (a box's
    // edge) are not joined: each side keeps its own guide.
    let smooth_seam_cos = crate::mesh::CREASE_DEG.to_radians().cos();
    let mut pairs: Vec<((u32, u32), f64)> = weights
        .into_iter()
        .map(|(k, w)| (k, w.max(floor)))
        .chain(
            mesh.weld
                .iter()
                .enumerate()
                .filter(|&(i, &w)| {
                    w as usize != i && normals[i].dot(normals[w as usize]) > smooth_seam_cos
                })
                .map(|(i, &w)| ((w.min(i as u32), w.max(i as u32)), stiff)),
        )
        .collect();
    pairs.sort_unstable_by_key(|p| p.0);
    pairs.dedup_by_key(|p| p.0);
    pairs
        .into_iter()
        .map(|((a, b), w)| {
            let (ia, ib) = (a as usize, b as usize);
            Link {
                a,
                b,
                rot: transport(normals[ia], basis[ia], normals[ib], basis[ib]),
                w,
            }
        })
        .collect()
}

/// The area each vertex stands for: a third of its triangles'.
fn vertex_areas(mesh: &Mesh) -> Vec<f64> {
    let mut area = vec![0.0; mesh.positions.len()];
    for (t, tri) in mesh.triangles.iter().enumerate() {
        for &i in tri {
            area[i as usize] += mesh.area(t) as f64 / 3.0;
        }
    }
    area
}

/// The connected parts of the graph, as lists of vertices.
fn parts(n: usize, links: &[Link]) -> Vec<Vec<u32>> {
    let mut sets = DisjointSets::new(n);
    for l in links {
        sets.join(l.a, l.b);
    }
    let mut groups: std::collections::BTreeMap<u32, Vec<u32>> = Default::default();
    for i in 0..n as u32 {
        groups.entry(sets.root(i)).or_default().push(i);
    }
    groups.into_values().collect()
}

/// The connection Laplacian of one part plus `shift` times its mass
/// matrix, in local indices.
struct Operator {
    /// (a, b, rot, weight) with local indices.
    links: Vec<(usize, usize, DVec2, f64)>,
    degree: Vec<f64>,
    mass: Vec<f64>,
    shift: f64,
}

impl Operator {
    fn apply(&self, z: &[DVec2], out: &mut [DVec2]) {
        for (k, o) in out.iter_mut().enumerate() {
            *o = z[k] * (self.degree[k] + self.shift * self.mass[k]);
        }
        for &(a, b, r, w) in &self.links {
            out[a] -= mul(r, z[b]) * w;
            out[b] -= mul(conj(r), z[a]) * w;
        }
    }

    /// Conjugate gradients for (L + shift M) x = rhs, from x, with the
    /// diagonal as preconditioner (the cotangent weights of a fine,
    /// irregular mesh vary by orders of magnitude from vertex to vertex).
    fn solve(&self, rhs: &[DVec2], x: &mut [DVec2]) {
        let n = rhs.len();
        let dot = |u: &[DVec2], v: &[DVec2]| u.iter().zip(v).map(|(a, b)| a.dot(*b)).sum::<f64>();
        let inv_diag: Vec<f64> = (0..n)
            .map(|k| 1.0 / (self.degree[k] + self.shift * self.mass[k]).max(f64::MIN_POSITIVE))
            .collect();
        let mut ax = vec![DVec2::ZERO; n];
        self.apply(x, &mut ax);
        let mut r: Vec<DVec2> = rhs.iter().zip(&ax).map(|(b, a)| *b - *a).collect();
        let mut z: Vec<DVec2> = r.iter().zip(&inv_diag).map(|(r, d)| *r * *d).collect();
        let mut p = z.clone();
        let mut rz = dot(&r, &z);
        let stop = 1e-16 * dot(rhs, rhs).max(f64::MIN_POSITIVE);
        let mut ap = vec![DVec2::ZERO; n];
        for _ in 0..20 * n.max(50) {
            if dot(&r, &r) <= stop {
                break;
            }
            self.apply(&p, &mut ap);
            // The operator is Hermitian, so Re<p, Ap> is <p, Ap>.
            let alpha = rz / dot(&p, &ap);
            for k in 0..n {
                x[k] += p[k] * alpha;
                r[k] -= ap[k] * alpha;
                z[k] = r[k] * inv_diag[k];
            }
            let rz_new = dot(&r, &z);
            let beta = rz_new / rz;
            rz = rz_new;
            for k in 0..n {
                p[k] = z[k] + p[k] * beta;
            }
        }
    }
}

/// The field on one part (its vertices, `links`, `local` indices, vertex
/// areas and guide): the minimiser of <z, L z> + s |z - q|²_M, i.e.
/// (L + s M) z = s M q, a smooth field that follows the guide q where the
/// guide is strong (Knöppel et al. 2013, section 6).
fn guided(
    part: &[u32],
    links: &[Link],
    local: &[u32],
    area: &[f64],
    guide: &[DVec2],
    s: f64,
) -> Vec<DVec2> {
    let n = part.len();
    let mut degree = vec![0.0; n];
    let links: Vec<(usize, usize, DVec2, f64)> = links
        .iter()
        .map(|l| {
            let (a, b) = (local[l.a as usize] as usize, local[l.b as usize] as usize);
            degree[a] += l.w;
            degree[b] += l.w;
            (a, b, l.rot, l.w)
        })
        .collect();
    let mass: Vec<f64> = part.iter().map(|&i| area[i as usize]).collect();
    let q: Vec<DVec2> = part.iter().map(|&i| guide[i as usize]).collect();
    let rhs: Vec<DVec2> = q.iter().zip(&mass).map(|(v, m)| *v * (s * m)).collect();
    let op = Operator {
        links,
        degree,
        mass,
        shift: s,
    };
    let mut z = q;
    op.solve(&rhs, &mut z);
    z
}

impl TangentField {
    /// The field on `mesh`: smooth over a fifth of the object's size, and
    /// beyond that following the object's up direction (+z) projected on
    /// the surface (+x on a part that is level throughout). Where +z
    /// stands normal to the surface (the top of a sphere) the guide fades
    /// and the field turns about the pole as a surface of revolution's
    /// meridians do.
    pub fn new(mesh: &Mesh) -> TangentField {
        let n = mesh.positions.len();
        let (lo, hi) = mesh.bounds();
        let smoothing_mm = SMOOTHING * (hi - lo).length();
        let normals = vertex_normals(mesh);
        let basis = bases(&normals);
        let links = links(mesh, &normals, &basis);
        let area = vertex_areas(mesh);
        let project = |axis: Vec3| -> Vec<DVec2> {
            basis
                .iter()
                .map(|(e1, e2)| DVec2::new(axis.dot(*e1) as f64, axis.dot(*e2) as f64))
                .collect()
        };
        let (up, level) = (project(Vec3::Z), project(Vec3::X));
        let s = 1.0 / (smoothing_mm as f64).powi(2).max(f64::MIN_POSITIVE);
        let parts = parts(n, &links);
        // Local index of every vertex within its part.
        let mut local = vec![u32::MAX; n];
        for p in &parts {
            for (k, &i) in p.iter().enumerate() {
                local[i as usize] = k as u32;
            }
        }
        let mut by_part: Vec<Vec<Link>> = vec![Vec::new(); parts.len()];
        let mut part_of = vec![0usize; n];
        for (k, p) in parts.iter().enumerate() {
            for &i in p {
                part_of[i as usize] = k;
            }
        }
        for l in &links {
            by_part[part_of[l.a as usize]].push(*l);
        }
        let fields: Vec<Vec<DVec2>> = parts
            .par_iter()
            .zip(&by_part)
            .map(|(p, l)| {
                // A part that is level almost everywhere (a box's top face)
                // follows +x instead.
                let weight: f64 = p.iter().map(|&i| area[i as usize]).sum();
                let tilt: f64 = p
                    .iter()
                    .map(|&i| up[i as usize].length() * area[i as usize])
                    .sum();
                let guide = if tilt > LEVEL_TILT * weight {
                    &up
                } else {
                    &level
                };
                guided(p, l, &local, &area, guide, s)
            })
            .collect();
        let mut tangents = vec![Vec3::ZERO; n];
        for (p, z) in parts.iter().zip(fields) {
            // Unit mean length per part; the length itself is kept, so that
            // near a singularity (where it falls to 0) interpolation leans on
            // the vertices whose direction is well defined.
            let mean = z.iter().map(|v| v.length()).sum::<f64>() / z.len().max(1) as f64;
            let scale = if mean > 0.0 { 1.0 / mean } else { 0.0 };
            for (&i, v) in p.iter().zip(z) {
                let (e1, e2) = basis[i as usize];
                tangents[i as usize] = (e1 * v.x as f32 + e2 * v.y as f32) * scale as f32;
            }
        }
        TangentField { tangents }
    }

    /// The tangent at barycentrics (b1, b2) of triangle `t`, unnormalised
    /// (project it onto the shading plane, as [`crate::points::frame`] does).
    pub fn at(&self, mesh: &Mesh, t: usize, b1: f32, b2: f32) -> Vec3 {
        let [a, b, c] = mesh.triangles[t].map(|i| self.tangents[i as usize]);
        a * (1.0 - b1 - b2) + b * b1 + c * b2
    }

    /// [`frame_jumps`] of this field, taken at the triangles' centres.
    pub fn frame_jumps(&self, mesh: &Mesh, limit_deg: f32) -> FrameJumps {
        frame_jumps(mesh, |t| self.at(mesh, t, 1.0 / 3.0, 1.0 / 3.0), limit_deg)
    }
}

/// How many of the mesh's inner edges the tangent frame turns across by
/// more than `limit_deg`: `tangent(t)` is triangle t's frame direction,
/// compared with its neighbour's after parallel transport over the shared
/// edge (coincident vertices count as one, so patch borders and UV seams
/// are inner edges too). Edges where the surface itself folds by more than
/// [`crate::mesh::CREASE_DEG`] (a box's edges, a rim's corners) have no
/// tangent plane to carry a frame over; they are counted apart.
pub fn frame_jumps(mesh: &Mesh, tangent: impl Fn(usize) -> Vec3, limit_deg: f32) -> FrameJumps {
    let mut faces: std::collections::HashMap<(u32, u32), Vec<usize>> = Default::default();
    for (t, tri) in mesh.triangles.iter().enumerate() {
        let w = tri.map(|i| mesh.weld[i as usize]);
        for k in 0..3 {
            let (a, b) = (w[k], w[(k + 1) % 3]);
            faces.entry((a.min(b), a.max(b))).or_default().push(t);
        }
    }
    let cos_limit = limit_deg.to_radians().cos();
    let cos_crease = crate::mesh::CREASE_DEG.to_radians().cos();
    let frame = |t: usize| {
        let n = mesh.face_normal(t);
        (n, (tangent(t) - n * n.dot(tangent(t))).normalize_or_zero())
    };
    let (smooth, creases): (Vec<(usize, usize)>, Vec<_>) = faces
        .values()
        .filter(|f| f.len() == 2)
        .map(|f| (f[0], f[1]))
        .partition(|&(f, g)| mesh.face_normal(f).dot(mesh.face_normal(g)) >= cos_crease);
    let over = smooth
        .iter()
        .filter(|&&(f, g)| {
            let ((nf, tf), (ng, tg)) = (frame(f), frame(g));
            tf.dot(Quat::from_rotation_arc(ng, nf) * tg) < cos_limit
        })
        .count();
    FrameJumps {
        edges: smooth.len(),
        over,
        creases: creases.len(),
    }
}

/// The result of [`TangentField::frame_jumps`]: of `edges` inner edges off
/// creases, `over` turn by more than the limit; `creases` edges were not
/// judged.
#[derive(Clone, Copy, Debug)]
pub struct FrameJumps {
    pub edges: usize,
    pub over: usize,
    pub creases: usize,
}

impl FrameJumps {
    pub fn share(&self) -> f64 {
        self.over as f64 / self.edges.max(1) as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The +u direction of a box projection (drop the normal's dominant
    /// axis), the placement this field replaces.
    fn box_projection_tangent(p: [Vec3; 3]) -> Vec3 {
        let n = (p[1] - p[0]).cross(p[2] - p[0]).abs();
        if n.x > n.z && n.x >= n.y {
            Vec3::Y
        } else {
            Vec3::X
        }
    }
    use crate::builtin::{TEAPOT_CELL, slab, sphere, teapot};

    #[test]
    fn the_field_is_the_same_bits_every_time() {
        // Every HashMap has its own iteration order: a float sum over one
        // shows up as last-bit differences between builds of the field.
        let m = teapot(12.0, 0.1).unwrap();
        let first = TangentField::new(&m).tangents;
        for _ in 0..6 {
            let again = TangentField::new(&m).tangents;
            assert!(again == first, "the field differs between builds");
        }
    }

    #[test]
    fn a_flat_face_gets_one_direction() {
        let m = slab(20.0, 5.0).unwrap();
        let f = TangentField::new(&m);
        let top: Vec<Vec3> = (0..m.positions.len())
            .filter(|&i| m.normals[i].z > 0.9)
            .map(|i| f.tangents[i])
            .collect();
        assert_eq!(top.len(), 4);
        for t in &top {
            assert!(t.dot(Vec3::X) > 0.999, "{t}");
        }
        // The sides follow the up direction.
        for i in (0..m.positions.len()).filter(|&i| m.normals[i].z.abs() < 0.1) {
            assert!(f.tangents[i].dot(Vec3::Z) > 0.999, "{}", f.tangents[i]);
        }
    }

    #[test]
    fn the_teapot_and_sphere_fields_do_not_jump() {
        for (name, m) in [
            ("teapot", teapot(12.0, TEAPOT_CELL).unwrap()),
            ("sphere", sphere(20.0, 96, 48).unwrap()),
        ] {
            let f = TangentField::new(&m);
            let j = f.frame_jumps(&m, 10.0);
            eprintln!("{name}: {j:?}");
            assert!(j.share() < 0.01, "{name}: {j:?}");
            // The check can fail: a field of random directions jumps.
            let random = TangentField {
                tangents: (0..m.positions.len())
                    .map(|k| {
                        let a = k as f32 * 2.4;
                        let n = m.normals[k];
                        let e1 = n.any_orthonormal_vector();
                        e1 * a.cos() + n.cross(e1) * a.sin()
                    })
                    .collect(),
            };
            assert!(random.frame_jumps(&m, 10.0).share() > 0.5, "{name}");
            // So does the box projection's frame, which switches axis.
            let boxed = frame_jumps(&m, |t| box_projection_tangent(m.corners(t)), 10.0);
            eprintln!("{name} box projection: {boxed:?}");
            assert!(boxed.share() > 0.01, "{name}: {boxed:?}");
        }
    }
}
