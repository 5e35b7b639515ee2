//! Photons through a cellular medium ([`crate::cells`]): the solid is the
//! wall material below the top surface minus the air cells. A photon in air
//! (above the top, or in a cell) flies straight until it meets a wall or the
//! top, or leaves to the sky; light leaving the top or a cell wall into an
//! open cell can meet a wall again and re-enter. At every wall and at the
//! top it is reflected or refracted by sampling that boundary's rough
//! dielectric (GGX, exact Fresnel). On the top, the single-scattering
//! microfacet model kills the masked share as on any sample. At the cell
//! walls, which a path crosses hundreds of times, that loss (a few per cent
//! per crossing) would act as a strong absorption, so a masked or
//! rejected sample is drawn again: the walls conserve energy, their
//! multiple-scattered share returned to the single-scattering lobe (its
//! density f |cos| / A, A the wall's albedo [`crate::microfacet::SingleScatteringAlbedo`]).
//! Inside the walls it random-walks as in a homogeneous medium. Every
//! boundary event is splatted into every camera through that density (the
//! BSDF at the top, f / A at a wall), with visibility traced through the
//! air (cells included) towards the camera.

use glam::Vec3;

use crate::cells::Cells;
use crate::medium::Volume;
use crate::microfacet::{Dielectric, TransportMode};
use crate::rng::{WalkRng, exp1_from_bits};
use crate::surface::HeightField;
use crate::walk::{
    Local, MAX_EVENTS, MAX_INTERFACES, Pass, SurfaceKind, Tally, geometric_events,
    resampled_direction, sample_uniform_sphere_bits,
};

/// Which boundary a hit is on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Boundary {
    /// The sample's top surface.
    Top,
    /// A cell wall.
    Wall,
}

/// Where a ray in the air meets the solid.
#[derive(Debug, Clone, Copy)]
pub struct SolidHit {
    pub x: Vec3,
    /// Unit normal into the air.
    pub n: Vec3,
    pub boundary: Boundary,
}

/// How a ray in the air ends.
#[derive(Debug, Clone, Copy)]
pub enum AirEnd {
    Hit(SolidHit),
    /// Left upwards (or past the footprint) with nothing in the way.
    Sky,
    /// Left the slab through its black sides or bottom inside a cell.
    Lost,
}

enum CellEnd {
    Missed,
    Reflected,
    Exited,
    Absorbed,
    Escaped,
    SurfaceLoss,
    Truncated,
}

enum WallEnd {
    /// Left the wall at `x` (normal `n` into the air) along `d`.
    Left(Vec3, Vec3, Vec3),
    Ended(CellEnd),
}

impl Pass<'_> {
    /// Fly from `p` in the air along the unit direction `d` until the solid
    /// (top surface or cell wall) or the sky.
    pub fn air_ray(&self, vol: &Volume, cells: &Cells, mut p: Vec3, d: Vec3) -> AirEnd {
        let hf = &self.scene.surface;
        let [hx, hy, depth] = vol.half;
        let outside = |x: Vec3| x.x.abs() > hx || x.y.abs() > hy || x.z < -depth;
        for _ in 0..256 {
            let under_top = hf.inside_footprint(p.x, p.y) && below_top(hf, p);
            if !under_top {
                let Some((_, c)) = hf.hit_from_air(p, d) else {
                    return AirEnd::Sky;
                };
                // where the top is cut by a cell, the ray goes on in it
                let q = c + d * 1e-4;
                if cells.inside(q) {
                    p = q;
                    continue;
                }
                return AirEnd::Hit(SolidHit {
                    x: c,
                    n: hf.normal(c.x, c.y),
                    boundary: Boundary::Top,
                });
            }
            if outside(p) {
                return AirEnd::Lost;
            }
            // (None: a point within rounding of a wall, after a grazing hit)
            let Some(h) = cells.cross(p, d) else {
                return AirEnd::Lost;
            };
            let x = p + d * h.t;
            if outside(x) {
                return AirEnd::Lost;
            }
            if !hf.inside_footprint(x.x, x.y) || !below_top(hf, x) {
                // the cell opens above the top: on through the air
                p = x;
                continue;
            }
            return AirEnd::Hit(SolidHit {
                x,
                n: h.normal,
                boundary: Boundary::Wall,
            });
        }
        AirEnd::Lost
    }

    /// Whether a point on a boundary (normal `n` into the air) sees the sky along `w`.
    #[inline]
    fn air_visible(&self, vol: &Volume, cells: &Cells, x: Vec3, n: Vec3, w: Vec3) -> bool {
        matches!(self.air_ray(vol, cells, x + n * 1e-4, w), AirEnd::Sky)
    }

    /// One photon's whole life in a cellular sample.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn trace_cells(
        &self,
        vol: &Volume,
        cells: &Cells,
        o: Vec3,
        d: Vec3,
        rng: &mut WalkRng,
        table: &[(f32, f32)],
        t: &mut Tally,
    ) {
        let SurfaceKind::Dielectric(top) = &self.scene.kind else {
            t.missed += 1;
            return;
        };
        let (st, alb) = table[0];
        // absorbed at wall event N (geometric), whatever the walls in between
        let absorb_at = geometric_events(alb, rng.next_u64());
        let mut walk = WallState {
            st,
            absorb_at,
            limit: absorb_at.min(MAX_EVENTS as u64),
            events: 0,
        };
        let (mut p, mut d) = (o, d);
        let (mut touched, mut entered) = (false, false);
        let mut last_exit = Vec3::ZERO;
        let mut interfaces = 0u32;
        let end = loop {
            interfaces += 1;
            if interfaces > MAX_INTERFACES {
                break CellEnd::Truncated;
            }
            let h = match self.air_ray(vol, cells, p, d) {
                AirEnd::Sky => {
                    break if !touched {
                        CellEnd::Missed
                    } else if entered {
                        if let Some(g) = self.exits {
                            g.record(last_exit);
                        }
                        CellEnd::Exited
                    } else {
                        CellEnd::Reflected
                    };
                }
                AirEnd::Lost => break CellEnd::Escaped,
                AirEnd::Hit(h) => h,
            };
            touched = true;
            let local = Local::new(h.n);
            let wo = local.to_local(-d);
            let Some(wi) =
                self.cell_boundary(vol, cells, top, h.boundary, h.x, h.n, &local, wo, rng, t)
            else {
                break CellEnd::SurfaceLoss;
            };
            d = local.to_world(wi);
            if wi.z > 0.0 {
                p = h.x + h.n * 1e-4;
                continue;
            }
            if !entered {
                entered = true;
                t.entered += 1;
            }
            match self.wall_walk(vol, cells, top, h.x - h.n * 1e-4, d, rng, &mut walk, t) {
                WallEnd::Left(x, n, d2) => {
                    last_exit = x;
                    p = x + n * 1e-4;
                    d = d2;
                }
                WallEnd::Ended(e) => break e,
            }
        };
        t.events += walk.events;
        match end {
            CellEnd::Missed => t.missed += 1,
            CellEnd::Reflected => t.reflected += 1,
            CellEnd::Exited => t.exited += 1,
            CellEnd::Absorbed => t.absorbed += 1,
            CellEnd::Escaped => t.escaped += 1,
            CellEnd::SurfaceLoss => t.surface_loss += 1,
            CellEnd::Truncated => t.truncated += 1,
        }
    }

    /// The random walk inside the wall material from `p` along `d`, until
    /// the photon leaves it into the air (a cell or above the top) or ends.
    #[allow(clippy::too_many_arguments)]
    #[inline(never)]
    fn wall_walk(
        &self,
        vol: &Volume,
        cells: &Cells,
        top: &Dielectric,
        mut p: Vec3,
        mut d: Vec3,
        rng: &mut WalkRng,
        w: &mut WallState,
        tally: &mut Tally,
    ) -> WallEnd {
        let hf = &self.scene.surface;
        let [hx, hy, depth] = vol.half;
        let outside = |x: Vec3| x.x.abs() > hx || x.y.abs() > hy || x.z < -depth;
        let inv_st = 1.0 / w.st;
        loop {
            let dist = exp1_from_bits(rng.next_u32()) * inv_st;
            let top_hit = hf.crossing_from_below(p, d, dist);
            let lim = top_hit.map_or(dist, |(t, _)| t);
            let (x, n, boundary) = if let Some(h) = cells.first_entry(p, d, lim) {
                let x = p + d * h.t;
                if outside(x) {
                    return WallEnd::Ended(CellEnd::Escaped);
                }
                (x, h.normal, Boundary::Wall)
            } else if let Some((_, x)) = top_hit {
                if !hf.inside_footprint(x.x, x.y) {
                    return WallEnd::Ended(CellEnd::Escaped);
                }
                (x, hf.normal(x.x, x.y), Boundary::Top)
            } else {
                p += d * dist;
                if outside(p) {
                    return WallEnd::Ended(CellEnd::Escaped);
                }
                w.events += 1;
                if w.events >= w.limit {
                    return WallEnd::Ended(if w.events == w.absorb_at {
                        CellEnd::Absorbed
                    } else {
                        CellEnd::Truncated
                    });
                }
                d = sample_uniform_sphere_bits(rng.next_u64());
                continue;
            };
            let local = Local::new(n);
            let wo = local.to_local(-d);
            let Some(wi) =
                self.cell_boundary(vol, cells, top, boundary, x, n, &local, wo, rng, tally)
            else {
                return WallEnd::Ended(CellEnd::SurfaceLoss);
            };
            let d2 = local.to_world(wi);
            if wi.z > 0.0 {
                return WallEnd::Left(x, n, d2);
            }
            d = d2;
            p = x - n * 1e-4;
        }
    }
}

impl Pass<'_> {
    /// A boundary event in a cellular sample at `x` (normal `n` into the
    /// air): splat towards the cameras (visibility through the air), then
    /// sample reflection or refraction (see the module documentation for
    /// the walls' resampling).
    #[allow(clippy::too_many_arguments)]
    #[inline]
    fn cell_boundary(
        &self,
        vol: &Volume,
        cells: &Cells,
        top: &Dielectric,
        boundary: Boundary,
        x: Vec3,
        n: Vec3,
        local: &Local,
        wo: Vec3,
        rng: &mut WalkRng,
        t: &mut Tally,
    ) -> Option<Vec3> {
        let visible = |y: Vec3, w: Vec3| self.air_visible(vol, cells, y, n, w);
        match boundary {
            Boundary::Top => self.boundary_event_with(x, local, wo, top, true, rng, visible),
            Boundary::Wall => {
                t.wall_events += 1;
                let bsdf = &cells.wall;
                // the resampled wall's density towards wi is f |cos| / A(wo)
                let inv_a = 1.0 / cells.albedo.at(wo);
                self.splat_with(
                    x,
                    local,
                    |wi| bsdf.f(wo, wi, TransportMode::Importance) * inv_a,
                    visible,
                );
                resampled_direction(bsdf, wo, rng)
            }
        }
    }
}

/// `x.z <= h(x.y, x.y)`, skipping the height field's lookup well below its
/// lowest or above its highest point (the margin covers interpolation's rounding).
#[inline(always)]
fn below_top(hf: &HeightField, x: Vec3) -> bool {
    if x.z < hf.h_min - 1e-4 {
        true
    } else if x.z > hf.h_max + 1e-4 {
        false
    } else {
        x.z <= hf.height(x.x, x.y)
    }
}

/// The walk's state carried across the wall segments of one photon.
struct WallState {
    st: f32,
    absorb_at: u64,
    limit: u64,
    events: u64,
}
