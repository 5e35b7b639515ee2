//! What a render is asked for and what it reports: the mode (which terms
//! of eq. 4, paper Fig. 9), the quality and output settings with their
//! validation and memory estimate, and the timings and counts of a render.

use std::str::FromStr;

use crate::error::RenderError;
use crate::texture_synthesis::SynthSettings;

/// Which terms of eq. 4 are rendered (paper Fig. 9).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    Full,
    LrfOnly,
    LrfDipole,
    DipoleOnly,
}

impl Mode {
    pub const NAMES: [&str; 4] = ["full", "lrf-only", "lrf-dipole", "dipole-only"];

    pub(crate) fn has_lrf(self) -> bool {
        matches!(self, Mode::Full | Mode::LrfOnly | Mode::LrfDipole)
    }
    pub(crate) fn has_global(self) -> bool {
        !matches!(self, Mode::LrfOnly)
    }
    pub(crate) fn plain_dipole(self) -> bool {
        matches!(self, Mode::LrfDipole | Mode::DipoleOnly)
    }
}

impl FromStr for Mode {
    type Err = RenderError;
    fn from_str(s: &str) -> Result<Mode, RenderError> {
        Ok(match s {
            "full" => Mode::Full,
            "lrf-only" | "btf" => Mode::LrfOnly,
            "lrf-dipole" => Mode::LrfDipole,
            "dipole-only" | "dipole" => Mode::DipoleOnly,
            _ => {
                return Err(RenderError::Settings(format!(
                    "mode {s:?} (expected one of {})",
                    Mode::NAMES.join(", ")
                )));
            }
        })
    }
}

/// Quality and output settings.
#[derive(Clone, Debug)]
pub struct RenderSettings {
    pub width: u32,
    pub height: u32,
    /// Camera samples per pixel (stratified).
    pub spp: u32,
    pub mode: Mode,
    /// Target number of surface samples for the dipole (Poisson disk).
    pub surface_samples: usize,
    /// Octree solid-angle bound: a node is one sample when A / d^2 < epsilon.
    pub epsilon: f32,
    /// Environment samples per surface sample (irradiance pass).
    pub env_samples: usize,
    /// Environment samples per camera sample for the LRF.
    pub light_samples: usize,
    /// Radius of the local disk A_o left out of the dipole sum, mm (0 = none).
    pub local_radius_mm: f32,
    /// Irradiance interpolation: radius of the near field whose samples'
    /// irradiance is averaged instead of summed, in units of one sample's
    /// equal-area radius sqrt(A / pi) (0 = plain sum; see
    /// [`crate::octree::RdTable::with_near_field`]).
    pub near_field: f32,
    /// The dipole's exit-plane geometry factor on curved and thin objects
    /// ([`crate::octree::RdTable::with_geometry`]).
    pub geometry: bool,
    /// Within the geometry factor, the gain of a curved surface from
    /// diffusion theory in a sphere ([`crate::curvature`]).
    pub curvature: bool,
    /// Rays per surface sample for the light the object sends itself (two
    /// bounces of the global term, [`crate::interreflection`]; 0 = none).
    pub indirect_rays: usize,
    pub seed: u64,
    /// Synthesize the material texture on the surface (else tile it over
    /// the mesh's texture coordinates).
    pub synthesis: bool,
    pub synth: SynthSettings,
    /// Show a progress bar on stderr.
    pub progress: bool,
}

impl Default for RenderSettings {
    fn default() -> Self {
        RenderSettings {
            width: 512,
            height: 512,
            spp: 4,
            mode: Mode::Full,
            surface_samples: 30_000,
            epsilon: 0.1,
            env_samples: 64,
            light_samples: 8,
            local_radius_mm: 0.0,
            near_field: NEAR_FIELD_SPREAD,
            geometry: true,
            curvature: true,
            indirect_rays: 8,
            seed: 1,
            synthesis: true,
            synth: SynthSettings::default(),
            progress: false,
        }
    }
}

impl RenderSettings {
    pub fn validate(&self) -> Result<(), RenderError> {
        let bad = |m: String| Err(RenderError::Settings(m));
        if self.width == 0 || self.height == 0 || self.width > 16384 || self.height > 16384 {
            return bad(format!(
                "width/height {}x{} must be in 1..=16384",
                self.width, self.height
            ));
        }
        if self.spp == 0 || self.spp > 4096 {
            return bad(format!("spp {} must be in 1..=4096", self.spp));
        }
        if self.surface_samples == 0 || self.surface_samples > 5_000_000 {
            return bad(format!(
                "surface_samples {} must be in 1..=5e6",
                self.surface_samples
            ));
        }
        if !(self.epsilon.is_finite() && self.epsilon >= 0.0) {
            return bad(format!("epsilon {} must be >= 0", self.epsilon));
        }
        if !(self.local_radius_mm.is_finite() && self.local_radius_mm >= 0.0) {
            return bad(format!(
                "local_radius_mm {} must be >= 0",
                self.local_radius_mm
            ));
        }
        if !(self.near_field.is_finite() && (0.0..=100.0).contains(&self.near_field)) {
            return bad(format!("near_field {} must be in 0..=100", self.near_field));
        }
        if self.indirect_rays > 1024 {
            return bad(format!(
                "indirect_rays {} must be <= 1024",
                self.indirect_rays
            ));
        }
        if self.env_samples > 65536 || self.light_samples > 65536 {
            return bad("env_samples/light_samples must be <= 65536".into());
        }
        Ok(())
    }
}

/// Peak memory of the pixel pass per pixel: each tile's radiance and the
/// image they are gathered into (f32 RGB each, 24 B), and the tone map's
/// and encoder's buffers (a 4096 x 4096 PNG peaked at 427 MiB).
const BYTES_PER_PIXEL: u64 = 26;
/// Memory per surface sample: its position, normal, triangle, area and
/// irradiance, the octree nodes over it and the Poisson disk's candidates.
const BYTES_PER_SURFACE_SAMPLE: u64 = 256;

impl RenderSettings {
    /// Memory the render itself will take, bytes: the image and the
    /// surface samples (the mesh and the material are loaded already).
    pub fn memory_estimate(&self) -> u64 {
        let pixels = u64::from(self.width) * u64::from(self.height);
        let samples = if self.mode.has_global() {
            self.surface_samples as u64
        } else {
            0
        };
        // The light between parts keeps, per sample, its direct light (24 B),
        // a list (24 B) and up to one 16 B entry per ray that comes back.
        let indirect = if self.indirect_rays > 0 {
            48 + 16 * self.indirect_rays as u64
        } else {
            0
        };
        pixels * BYTES_PER_PIXEL + samples * (BYTES_PER_SURFACE_SAMPLE + indirect)
    }

    /// The memory estimate, refused when it exceeds `available` bytes
    /// (None: unknown, nothing is refused).
    pub fn check_memory(&self, available: Option<u64>) -> Result<u64, RenderError> {
        let need = self.memory_estimate();
        match available {
            Some(free) if need > free => Err(RenderError::Settings(format!(
                "{} x {} pixels with {} surface samples need about {}, but only {} of memory is \
                 available; lower --width/--height or --samples",
                self.width,
                self.height,
                self.surface_samples,
                human_bytes(need),
                human_bytes(free)
            ))),
            _ => Ok(need),
        }
    }
}

/// Memory the system can give without swapping (Linux `MemAvailable`).
pub fn available_memory() -> Option<u64> {
    let info = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = info.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// `1.5 GiB`, `24 MiB`.
pub fn human_bytes(b: u64) -> String {
    const MIB: f64 = 1024.0 * 1024.0;
    let mib = b as f64 / MIB;
    if mib >= 1024.0 {
        format!("{:.1} GiB", mib / 1024.0)
    } else {
        format!("{:.0} MiB", mib.max(1.0))
    }
}

/// Timings and counts of one render.
#[derive(Clone, Debug, Default)]
pub struct RenderStats {
    pub surface_samples: usize,
    pub octree_nodes: usize,
    /// The surface samples, with the tangent field beside them.
    pub secs_samples: f64,
    pub secs_irradiance: f64,
    /// The light between the object's parts, and how many rays came back.
    pub secs_interreflection: f64,
    pub rays_returned: usize,
    pub secs_tree: f64,
    pub secs_synthesis: f64,
    pub secs_pixels: f64,
    pub secs_total: f64,
    /// Dipole queries made and the nodes + points they summed.
    pub queries: u64,
    pub terms: u64,
}

/// Default [`RenderSettings::near_field`].
pub const NEAR_FIELD_SPREAD: f32 = 6.0;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn memory_estimate_counts_pixels_and_samples_and_refuses_what_is_not_there() {
        let s = RenderSettings {
            width: 16384,
            height: 16384,
            ..RenderSettings::default()
        };
        let need = s.memory_estimate();
        assert_eq!(need, 16384 * 16384 * 26 + 30_000 * (256 + 48 + 16 * 8));
        assert_eq!(human_bytes(need), "6.5 GiB");
        assert_eq!(s.check_memory(None).unwrap(), need);
        assert_eq!(s.check_memory(Some(need)).unwrap(), need);
        let e = s.check_memory(Some(4 << 30)).unwrap_err().to_string();
        assert!(e.contains("need about 6.5 GiB, but only 4.0 GiB"), "{e}");
        assert!(e.contains("--width/--height"), "{e}");
        // lrf-only has no surface samples.
        let lrf = RenderSettings {
            mode: Mode::LrfOnly,
            ..s
        };
        assert_eq!(lrf.memory_estimate(), 16384 * 16384 * 26);
    }
}
