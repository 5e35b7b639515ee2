//! One watertight surface from closed shells that may overlap, as the
//! teapot's handle and spout run into its body. A volumetric path tracer
//! needs the solid's one boundary: a surface buried inside another shell
//! would let light out of the middle of the object.
//!
//! The union's inside comes from winding numbers along the lines of a
//! grid (exact crossings of each line with the shells), its surface from
//! dual contouring (Ju et al. 2002): one vertex per cell the surface cuts,
//! placed by the exact crossings on the cell's edges and the shells'
//! normals there, and one quad per grid edge the surface cuts.

use std::collections::HashMap;

use glam::{DMat3, DVec3, Vec3};
use rayon::prelude::*;

use crate::mesh::weld_ids;
use crate::mesh_input::MeshInput;

/// Where a grid line crosses a shell: its coordinate along the line, +1 on
/// entering (the shell's normal against the line) or -1 on leaving, and the
/// shell's interpolated normal there.
#[derive(Clone, Copy)]
struct Crossing {
    t: f64,
    delta: i32,
    normal: Vec3,
}

/// A grid edge the union's surface cuts: its axis, its lower grid point, and
/// the crossing's position and normal.
struct EdgeCut {
    axis: usize,
    point: [usize; 3],
    position: Vec3,
    normal: Vec3,
}

struct Grid {
    lo: DVec3,
    cell: f64,
    n: [usize; 3],
}

impl Grid {
    fn index(&self, p: [usize; 3]) -> usize {
        p[0] + self.n[0] * (p[1] + self.n[1] * p[2])
    }

    fn coord(&self, axis: usize, i: usize) -> f64 {
        self.lo[axis] + self.cell * i as f64
    }
}

/// The surface of the union of `shells`, closed and consistently oriented
/// triangle meshes (outward normals by winding; `normals`, if given, per
/// vertex, else the faces'), on a grid of `cell` (in the shells' units).
/// Features thinner than a cell are thickened to one. The result has no
/// normals: [`crate::mesh::Mesh::build`] makes them, split at creases. It
/// is empty for empty shells or a cell that is not a positive number.
pub fn union_surface(shells: &MeshInput, cell: f32) -> MeshInput {
    if shells.triangles.is_empty() || !(cell.is_finite() && cell > 0.0) {
        return MeshInput::default();
    }
    let pos: Vec<DVec3> = shells
        .positions
        .iter()
        .map(|p| Vec3::from(*p).as_dvec3())
        .collect();
    let normals: Option<Vec<Vec3>> = shells
        .normals
        .as_ref()
        .map(|ns| ns.iter().map(|n| Vec3::from(*n)).collect());
    let (mut lo, mut hi) = (DVec3::splat(f64::MAX), DVec3::splat(f64::MIN));
    for p in &pos {
        lo = lo.min(*p);
        hi = hi.max(*p);
    }
    let cell = cell as f64;
    // Two cells of margin, and an offset no vertex sits on by chance, so no
    // grid line runs through a shell's edge or vertex.
    let lo = lo - DVec3::splat(2.0 * cell) - DVec3::new(0.317_2, 0.246_1, 0.139_3) * cell;
    let n = ((hi - lo) / cell)
        .ceil()
        .as_uvec3()
        .to_array()
        .map(|k| k as usize + 2);
    let grid = Grid { lo, cell, n };

    let lines: [Vec<Vec<Crossing>>; 3] = [0, 1, 2]
        .map(|axis| line_crossings(&grid, axis, &pos, normals.as_deref(), &shells.triangles));
    // The inside of every grid point, from the lines along z.
    let mut inside = vec![false; n[0] * n[1] * n[2]];
    for (l, crossings) in lines[2].iter().enumerate() {
        let (i, j) = (l % n[0], l / n[0]);
        for (k, state) in line_states(&grid, 2, crossings).into_iter().enumerate() {
            inside[grid.index([i, j, k])] = state;
        }
    }
    thicken_ambiguous_faces(&grid, &mut inside);
    let cuts = edge_cuts(&grid, &lines, &inside);
    nets(&grid, &cuts, &inside)
}

/// The crossings of every grid line along `axis` with the triangles, each
/// line's sorted by coordinate. Lines are indexed u + n_u v, with (u, v)
/// the axes after `axis` in cyclic order.
fn line_crossings(
    grid: &Grid,
    axis: usize,
    pos: &[DVec3],
    normals: Option<&[Vec3]>,
    triangles: &[[u32; 3]],
) -> Vec<Vec<Crossing>> {
    let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
    let (nu, nv) = (grid.n[u], grid.n[v]);
    let mut candidates: Vec<Vec<u32>> = vec![Vec::new(); nu * nv];
    let first = |x: f64, a: usize| ((x - grid.lo[a]) / grid.cell).ceil().max(0.0) as usize;
    let last =
        |x: f64, a: usize| (((x - grid.lo[a]) / grid.cell).floor() as usize).min(grid.n[a] - 1);
    for (f, t) in triangles.iter().enumerate() {
        let [a, b, c] = t.map(|i| pos[i as usize]);
        let (lo, hi) = (a.min(b).min(c), a.max(b).max(c));
        for iv in first(lo[v], v)..=last(hi[v], v) {
            for iu in first(lo[u], u)..=last(hi[u], u) {
                candidates[iu + nu * iv].push(f as u32);
            }
        }
    }
    candidates
        .par_iter()
        .enumerate()
        .map(|(l, tris)| {
            let q = (grid.coord(u, l % nu), grid.coord(v, l / nu));
            let mut hits: Vec<Crossing> = tris
                .iter()
                .filter_map(|&f| {
                    let t = triangles[f as usize];
                    let [a, b, c] = t.map(|i| pos[i as usize]);
                    // Edge functions in (u, v); each is exactly the negative
                    // of its neighbour's over a shared edge, so a line passes
                    // through exactly one of two neighbours.
                    let edge = |p: DVec3, r: DVec3| {
                        (p[u] - q.0) * (r[v] - q.1) - (p[v] - q.1) * (r[u] - q.0)
                    };
                    let w = [edge(b, c), edge(c, a), edge(a, b)];
                    let sum = w[0] + w[1] + w[2];
                    let same = w.iter().all(|&x| x >= 0.0) || w.iter().all(|&x| x <= 0.0);
                    if !same || sum == 0.0 {
                        return None;
                    }
                    let w = w.map(|x| x / sum);
                    let normal = match normals {
                        Some(ns) => {
                            let [na, nb, nc] = t.map(|i| ns[i as usize]);
                            na * w[0] as f32 + nb * w[1] as f32 + nc * w[2] as f32
                        }
                        None => (b - a).cross(c - a).as_vec3(),
                    };
                    Some(Crossing {
                        t: w[0] * a[axis] + w[1] * b[axis] + w[2] * c[axis],
                        // sum is twice the projected area: the geometric
                        // normal's component along the line.
                        delta: if sum < 0.0 { 1 } else { -1 },
                        normal: normal.normalize_or_zero(),
                    })
                })
                .collect();
            hits.sort_by(|x, y| x.t.total_cmp(&y.t));
            hits
        })
        .collect()
}

/// Inside (winding number above 0) at each grid point of one line.
fn line_states(grid: &Grid, axis: usize, crossings: &[Crossing]) -> Vec<bool> {
    let (mut winding, mut next) = (0, 0);
    (0..grid.n[axis])
        .map(|k| {
            let x = grid.coord(axis, k);
            while next < crossings.len() && crossings[next].t < x {
                winding += crossings[next].delta;
                next += 1;
            }
            winding > 0
        })
        .collect()
}

/// Turns grid points inside until no face of a cell has its inside corners
/// on one diagonal and its outside corners on the other. The contouring
/// would join four quads at such a face's edge (a part thinner than a
/// cell, as a rim's lip); thickening the part by a grid point keeps it and
/// makes the surface a manifold.
fn thicken_ambiguous_faces(grid: &Grid, inside: &mut [bool]) {
    let n = grid.n;
    loop {
        let mut flipped = 0;
        for axis in 0..3 {
            let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
            for k in 0..n[2] {
                for j in 0..n[1] {
                    for i in 0..n[0] {
                        let p = [i, j, k];
                        if p[u] + 1 >= n[u] || p[v] + 1 >= n[v] {
                            continue;
                        }
                        let corner = |du: usize, dv: usize| {
                            let mut q = p;
                            q[u] += du;
                            q[v] += dv;
                            grid.index(q)
                        };
                        let c = [corner(0, 0), corner(1, 0), corner(1, 1), corner(0, 1)];
                        let s = c.map(|q| inside[q]);
                        if s[0] == s[2] && s[1] == s[3] && s[0] != s[1] {
                            inside[if s[0] { c[1] } else { c[0] }] = true;
                            flipped += 1;
                        }
                    }
                }
            }
        }
        if flipped == 0 {
            return;
        }
    }
}

/// Every grid edge whose two ends differ in `inside`, with the crossing
/// where the line's winding number passes 0 (the mean position of the
/// edge, and no normal, if rounding hid it).
fn edge_cuts(grid: &Grid, lines: &[Vec<Vec<Crossing>>; 3], inside: &[bool]) -> Vec<EdgeCut> {
    let mut cuts = Vec::new();
    for (axis, lines) in lines.iter().enumerate() {
        let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
        for (l, crossings) in lines.iter().enumerate() {
            let mut point = [0; 3];
            point[u] = l % grid.n[u];
            point[v] = l / grid.n[u];
            let (mut winding, mut next) = (0, 0);
            for k in 0..grid.n[axis] - 1 {
                let (x0, x1) = (grid.coord(axis, k), grid.coord(axis, k + 1));
                while next < crossings.len() && crossings[next].t < x0 {
                    winding += crossings[next].delta;
                    next += 1;
                }
                point[axis] = k;
                let mut end = point;
                end[axis] = k + 1;
                let state = inside[grid.index(point)];
                if state == inside[grid.index(end)] {
                    continue;
                }
                // The last crossing in the segment after which the line is in
                // the end's state.
                let (mut w, mut found) = (winding, None);
                let mut i = next;
                while i < crossings.len() && crossings[i].t < x1 {
                    w += crossings[i].delta;
                    if (w > 0) != state {
                        found = Some(crossings[i]);
                    }
                    i += 1;
                }
                let mut at = DVec3::new(
                    grid.coord(0, point[0]),
                    grid.coord(1, point[1]),
                    grid.coord(2, point[2]),
                );
                let (t, normal) = found.map_or(((x0 + x1) / 2.0, Vec3::ZERO), |c| (c.t, c.normal));
                at[axis] = t;
                cuts.push(EdgeCut {
                    axis,
                    point,
                    position: at.as_vec3(),
                    normal,
                });
            }
        }
    }
    cuts
}

/// Dual contouring over the cut edges: a vertex per cut cell, a quad per
/// cut edge, oriented so its normal points out of the union.
fn nets(grid: &Grid, cuts: &[EdgeCut], inside: &[bool]) -> MeshInput {
    // The four cells around each cut edge, by their lowest grid point.
    let around = |c: &EdgeCut| {
        let (u, v) = ((c.axis + 1) % 3, (c.axis + 2) % 3);
        [(0, 0), (1, 0), (1, 1), (0, 1)].map(|(du, dv)| {
            let mut p = c.point;
            p[u] -= du;
            p[v] -= dv;
            grid.index(p)
        })
    };
    let mut vertex_of: HashMap<usize, u32> = HashMap::new();
    let mut cells: Vec<(usize, Vec<&EdgeCut>)> = Vec::new();
    for c in cuts {
        for cell in around(c) {
            let id = *vertex_of.entry(cell).or_insert_with(|| {
                cells.push((cell, Vec::new()));
                cells.len() as u32 - 1
            });
            cells[id as usize].1.push(c);
        }
    }
    let positions: Vec<Vec3> = cells
        .iter()
        .map(|(cell, cuts)| cell_vertex(grid, *cell, cuts))
        .collect();
    let mut triangles = Vec::with_capacity(2 * cuts.len());
    for c in cuts {
        let mut q = around(c).map(|cell| vertex_of[&cell]);
        if !inside[grid.index(c.point)] {
            q.reverse();
        }
        let p = q.map(|i| positions[i as usize]);
        // Split along the shorter diagonal.
        if p[0].distance_squared(p[2]) <= p[1].distance_squared(p[3]) {
            triangles.push([q[0], q[1], q[2]]);
            triangles.push([q[0], q[2], q[3]]);
        } else {
            triangles.push([q[0], q[1], q[3]]);
            triangles.push([q[1], q[2], q[3]]);
        }
    }
    MeshInput {
        positions: positions.iter().map(|p| p.to_array()).collect(),
        normals: None,
        uvs: None,
        triangles,
    }
}

/// A cut cell's vertex (dual contouring, Ju et al. 2002): the point
/// nearest, in least squares, to the tangent planes of its crossings,
/// pulled gently towards their mean so that a flat or creased patch keeps
/// it there along the free directions, and kept inside the cell. On a
/// crease or a corner it lands on the edge, not on the bevel that the
/// crossings' mean would cut.
fn cell_vertex(grid: &Grid, cell: usize, cuts: &[&EdgeCut]) -> Vec3 {
    let mean = cuts.iter().map(|c| c.position.as_dvec3()).sum::<DVec3>() / cuts.len() as f64;
    let (mut ata, mut atb) = (DMat3::ZERO, DVec3::ZERO);
    for c in cuts {
        let n = c.normal.as_dvec3();
        ata += DMat3::from_cols(n * n.x, n * n.y, n * n.z);
        atb += n * n.dot(c.position.as_dvec3() - mean);
    }
    let shift = (ata + DMat3::IDENTITY * 0.05).inverse() * atb;
    let corner = [
        cell % grid.n[0],
        (cell / grid.n[0]) % grid.n[1],
        cell / (grid.n[0] * grid.n[1]),
    ];
    let lo = DVec3::new(
        grid.coord(0, corner[0]),
        grid.coord(1, corner[1]),
        grid.coord(2, corner[2]),
    );
    (mean + shift)
        .clamp(lo, lo + DVec3::splat(grid.cell))
        .as_vec3()
}

/// Closes every hole of a mesh: each loop of boundary edges (positions
/// joined within `tol`) gets a fan of triangles to its centroid, wound
/// against the loop's own faces and with a flat normal of its own.
pub fn cap_holes(m: &mut MeshInput, tol: f32) {
    let pos: Vec<Vec3> = m.positions.iter().map(|p| Vec3::from(*p)).collect();
    let ids = weld_ids(&pos, tol);
    // Directed edges used once and never in reverse are boundary edges.
    let mut directed: HashMap<(u32, u32), u32> = HashMap::new();
    for t in &m.triangles {
        let w = t.map(|i| ids[i as usize]);
        for k in 0..3 {
            *directed.entry((w[k], w[(k + 1) % 3])).or_default() += 1;
        }
    }
    let mut next: Vec<(u32, u32)> = directed
        .keys()
        .filter(|&&(a, b)| a != b && !directed.contains_key(&(b, a)))
        .copied()
        .collect();
    next.sort_unstable();
    let successor: HashMap<u32, u32> = next.iter().copied().collect();
    let mut done = std::collections::HashSet::new();
    for &(start, _) in &next {
        if done.contains(&start) {
            continue;
        }
        let mut ring = vec![start];
        let mut at = successor[&start];
        while at != start && ring.len() <= next.len() {
            ring.push(at);
            match successor.get(&at) {
                Some(&b) => at = b,
                None => break,
            }
        }
        done.extend(ring.iter().copied());
        if at != start || ring.len() < 3 {
            continue; // not a simple loop: leave it open
        }
        let p: Vec<Vec3> = ring
            .iter()
            .map(|&i| Vec3::from(m.positions[i as usize]))
            .collect();
        let centre = p.iter().sum::<Vec3>() / p.len() as f32;
        // The boundary runs a -> b in its faces, so the cap runs b -> a.
        let normal = (0..p.len())
            .map(|k| (p[(k + 1) % p.len()] - centre).cross(p[k] - centre))
            .sum::<Vec3>()
            .normalize_or_zero();
        let base = m.positions.len() as u32;
        m.positions.push(centre.to_array());
        m.positions.extend(p.iter().map(|q| q.to_array()));
        if let Some(ns) = &mut m.normals {
            ns.extend(std::iter::repeat_n(normal.to_array(), p.len() + 1));
        }
        if let Some(uvs) = &mut m.uvs {
            uvs.extend(std::iter::repeat_n([0.0, 0.0], p.len() + 1));
        }
        for k in 0..p.len() as u32 {
            let (a, b) = (base + 1 + k, base + 1 + (k + 1) % p.len() as u32);
            m.triangles.push([b, a, base]);
        }
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::builtin::sphere;
    use std::f32::consts::PI;

    fn shells(parts: &[(Vec3, f32)]) -> MeshInput {
        let mut m = MeshInput {
            normals: Some(Vec::new()),
            ..Default::default()
        };
        for &(centre, r) in parts {
            let s = sphere(r, 64, 32).unwrap();
            let base = m.positions.len() as u32;
            for (p, n) in s.positions.iter().zip(&s.normals) {
                m.positions.push((*p - Vec3::Z * r + centre).to_array());
                m.normals.as_mut().unwrap().push(n.to_array());
            }
            m.triangles
                .extend(s.triangles.iter().map(|t| t.map(|i| i + base)));
        }
        m
    }

    pub(crate) fn volume(m: &MeshInput) -> f32 {
        m.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| Vec3::from(m.positions[i as usize]));
                a.dot(b.cross(c)) / 6.0
            })
            .sum()
    }

    /// Every edge in exactly two faces, once each way.
    pub(crate) fn is_closed(m: &MeshInput) -> bool {
        let mut directed: HashMap<(u32, u32), u32> = HashMap::new();
        for t in &m.triangles {
            for k in 0..3 {
                *directed.entry((t[k], t[(k + 1) % 3])).or_default() += 1;
            }
        }
        directed
            .iter()
            .all(|(&(a, b), &c)| c == 1 && directed.get(&(b, a)) == Some(&1))
    }

    #[test]
    fn two_overlapping_spheres_give_their_union() {
        let (r, d) = (10.0f32, 8.0f32);
        let input = shells(&[(Vec3::ZERO, r), (Vec3::new(d, 0.0, 0.0), r)]);
        let sphere_volume = 4.0 / 3.0 * PI * r.powi(3);
        let lens = PI * (4.0 * r + d) * (2.0 * r - d).powi(2) / 12.0;
        let exact = 2.0 * sphere_volume - lens;
        // The shells as given enclose both spheres whole: the lens twice.
        assert!((volume(&input) - exact).abs() / exact > 0.2);
        let u = union_surface(&input, 0.4);
        assert!(is_closed(&u));
        let v = volume(&u);
        assert!((v - exact).abs() / exact < 0.01, "{v} against {exact}");
        // Every vertex lies on the union's surface to within a cell.
        for p in &u.positions {
            let p = Vec3::from(*p);
            let sdf = (p.length() - r).min((p - Vec3::new(d, 0.0, 0.0)).length() - r);
            assert!(sdf.abs() < 0.4, "{p}: {sdf}");
        }
    }

    #[test]
    fn holes_are_capped_and_wound_with_their_mesh() {
        // A sphere without its top cap of triangles.
        let s = sphere(10.0, 32, 16).unwrap();
        let mut m = MeshInput {
            positions: s.positions.iter().map(|p| p.to_array()).collect(),
            normals: Some(s.normals.iter().map(|n| n.to_array()).collect()),
            uvs: None,
            triangles: s.triangles[64..].to_vec(),
        };
        let open = volume(&m);
        cap_holes(&mut m, 1e-4);
        let exact = 4.0 / 3.0 * PI * 1000.0;
        let capped = volume(&m);
        assert!((capped - exact).abs() / exact < 0.02, "{open} -> {capped}");
        let u = union_surface(&m, 0.5);
        assert!(is_closed(&u));
        assert!((volume(&u) - capped).abs() / capped < 0.01);
    }
}
