//! The world the acquisition code talks to: a built scene, the true rig and
//! a quality scale; `render_pose` makes per-camera radiance for one rig pose.

use glam::{DMat3, DVec3, Vec3};
use serde::{Deserialize, Serialize};

use crate::Error;
use crate::medium::Volume;
use crate::rig::RigTruth;
use crate::sample::{Relief, SceneDesc, TargetDesc};
use crate::sensor::Sensor;
use crate::surface::HeightField;
use crate::walk::{Accum, ExitGrid, Pass, Scene, Source, SplatCamera, SurfaceKind, Tally};

/// How finely the world is simulated.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SimQuality {
    /// Image binning: images are (1024 / downscale) x (768 / downscale).
    pub downscale: u32,
    /// Photons per laser stripe (one channel).
    pub laser_photons: u64,
    /// Photons per stripe while the world renders a capture's entrance pass
    /// ([`World::set_entrance_scan`]; None: `laser_photons`). Pass 1's
    /// stripes feed only the entrance function, which reads each stripe's
    /// flux summed over a band around its line: a sum over the whole
    /// stripe, it holds its noise at a fraction of the photons the vertical
    /// stripes' profile fits need. Calibration keeps `laser_photons` (its
    /// laser planes are fitted at every clamp position).
    #[serde(
        default,
        alias = "oblique_laser_photons",
        skip_serializing_if = "Option::is_none"
    )]
    pub entrance_laser_photons: Option<u64>,
    /// Photons per lamp and channel (per lamp on a calibration target, whose
    /// channels share them).
    pub lamp_photons: u64,
    /// Height-field grid spacing, mm.
    pub surface_cell_mm: f64,
}

impl SimQuality {
    /// CI scale: 128 x 96 images, 640 k photons per stripe, 40 k per lamp
    /// and channel; a whole capture fits in the test suite. R is a ratio of
    /// integrals that a few stripe images carry: at 40 k a stripe image of
    /// skin1's blue (a' 0.68) scattered 3.5 % about its mean, and a' by
    /// 0.003 from seed to seed.
    pub fn ci() -> Self {
        SimQuality {
            downscale: 8,
            laser_photons: 640_000,
            entrance_laser_photons: None,
            lamp_photons: 40_000,
            surface_cell_mm: 0.2,
        }
    }
    /// 256 x 192, 640 k photons per stripe (the reference white's laser
    /// flux: within 0.4 %, 0.65 % at 150 k), 100 k per lamp and channel.
    pub fn preview() -> Self {
        SimQuality {
            downscale: 4,
            laser_photons: 640_000,
            entrance_laser_photons: None,
            lamp_photons: 100_000,
            surface_cell_mm: 0.1,
        }
    }
    /// Full 1024 x 768, 1 M photons per light: a pose renders in seconds.
    pub fn default_scale() -> Self {
        SimQuality {
            downscale: 1,
            laser_photons: 1_000_000,
            entrance_laser_photons: None,
            lamp_photons: 1_000_000,
            surface_cell_mm: 0.1,
        }
    }
    /// Full size, 40 M photons (figures).
    pub fn final_scale() -> Self {
        SimQuality {
            downscale: 1,
            laser_photons: 40_000_000,
            entrance_laser_photons: None,
            lamp_photons: 30_000_000,
            surface_cell_mm: 0.05,
        }
    }
    pub fn by_name(name: &str) -> Result<Self, Error> {
        match name {
            "ci" => Ok(Self::ci()),
            "preview" => Ok(Self::preview()),
            "default" => Ok(Self::default_scale()),
            "final" => Ok(Self::final_scale()),
            other => Err(Error::UnknownQuality(other.into())),
        }
    }
}

impl Default for SimQuality {
    fn default() -> Self {
        Self::default_scale()
    }
}

/// A laser that is on: which one (0 red 650 nm, 1 green 532 nm, 2 blue
/// 473 nm = the colour channel it lights) and its drive, 0..=1 of full power.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LaserOn {
    pub channel: usize,
    pub power: f32,
}

/// The rig's state during one exposure (angles in radians).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Illumination {
    pub turntable_rad: f64,
    pub light_arc_rad: f64,
    /// Beam deflection of the galvo (optical angle), radians.
    pub galvo_rad: f64,
    pub laser: Option<LaserOn>,
    /// Bit k set: lamp k is on.
    pub lamps: u8,
}

/// A linear radiance image, W sr^-1 m^-2, row-major RGB.
#[derive(Debug, Clone, PartialEq)]
pub struct RadianceImage {
    pub width: u32,
    pub height: u32,
    pub data: Vec<[f32; 3]>,
}

impl RadianceImage {
    pub fn black(width: u32, height: u32) -> Self {
        RadianceImage {
            width,
            height,
            data: vec![[0.0; 3]; width as usize * height as usize],
        }
    }
    /// Sum over pixels of one channel (a check on total light).
    pub fn sum(&self, ch: usize) -> f64 {
        self.data.iter().map(|p| p[ch] as f64).sum()
    }
}

/// Radiance seen by every requested camera at one rig pose, plus the photon tally.
#[derive(Debug, Clone)]
pub struct PoseRadiance {
    pub images: Vec<Option<RadianceImage>>,
    pub tally: Tally,
}

impl PoseRadiance {
    pub fn image(&self, camera: usize) -> Option<&RadianceImage> {
        self.images.get(camera).and_then(|i| i.as_ref())
    }
}

/// The simulated world.
#[derive(Debug, Clone)]
pub struct World {
    desc: SceneDesc,
    scene: Scene,
    rig: RigTruth,
    quality: SimQuality,
    laser_elevation: f64,
    entrance_scan: bool,
    vertex_nee: bool,
}

fn f32v(v: DVec3) -> Vec3 {
    v.as_vec3()
}

impl World {
    /// Build the scene (volume grid, height field) once.
    pub fn new(desc: SceneDesc, rig: RigTruth, quality: SimQuality) -> Result<World, Error> {
        desc.validate()?;
        if !(1..=64).contains(&quality.downscale) {
            return Err(Error::InvalidIllumination(format!(
                "downscale {} not in 1..=64",
                quality.downscale
            )));
        }
        if !(quality.surface_cell_mm.is_finite() && (0.01..=2.0).contains(&quality.surface_cell_mm))
        {
            return Err(Error::InvalidIllumination(
                "surface_cell_mm must be in [0.01, 2]".into(),
            ));
        }
        let scene = match &desc {
            SceneDesc::Sample(s) => {
                let volume = Volume::build(s);
                let half = [s.size_mm[0] as f32 / 2.0, s.size_mm[1] as f32 / 2.0];
                let sf = &s.surface;
                let surface = match sf.relief {
                    Relief::Flat => HeightField::flat(half, 0.0),
                    Relief::Bumps | Relief::Pores => {
                        let pores = if sf.relief == Relief::Pores {
                            volume.open_voids.as_slice()
                        } else {
                            &[]
                        };
                        HeightField::relief(
                            half,
                            quality.surface_cell_mm as f32,
                            sf.bump_amplitude_mm as f32,
                            sf.bump_scale_mm as f32,
                            pores,
                            s.seed,
                        )
                    }
                };
                Scene {
                    surface,
                    kind: SurfaceKind::Dielectric(sf.dielectric()),
                    volume: Some(volume),
                    top_albedo: sf.kept_albedo(),
                }
            }
            SceneDesc::Target { target } => {
                let surface = match target {
                    TargetDesc::TwoHeight {
                        low_mm,
                        high_mm,
                        size_mm,
                        ..
                    } => {
                        let h = *size_mm as f32 / 2.0;
                        HeightField::two_steps([h, h], *low_mm as f32, *high_mm as f32)
                    }
                    TargetDesc::Checkerboard {
                        size_mm, height_mm, ..
                    } => {
                        let h = *size_mm as f32 / 2.0;
                        HeightField::flat([h, h], *height_mm as f32)
                    }
                    TargetDesc::White { size_mm, .. } => {
                        let h = *size_mm as f32 / 2.0;
                        HeightField::flat([h, h], 0.0)
                    }
                    TargetDesc::ColourPattern { patch_mm } => {
                        // chart of 6 x 4 patches plus a one-patch black border
                        HeightField::flat([4.0 * *patch_mm as f32, 3.0 * *patch_mm as f32], 0.0)
                    }
                };
                Scene {
                    surface,
                    kind: SurfaceKind::Lambertian(target.clone()),
                    volume: None,
                    top_albedo: None,
                }
            }
        };
        Ok(World {
            desc,
            scene,
            rig,
            quality,
            laser_elevation: std::f64::consts::FRAC_PI_2,
            entrance_scan: false,
            vertex_nee: true,
        })
    }

    /// Clamp the laser unit at this (nominal) elevation on the light arc.
    pub fn set_laser_mount(&mut self, elevation_rad: f64) {
        self.laser_elevation = elevation_rad;
    }
    /// Whether the stripes now shot are a capture's entrance pass (pass 1),
    /// rendered with `SimQuality::entrance_laser_photons`.
    pub fn set_entrance_scan(&mut self, on: bool) {
        self.entrance_scan = on;
    }
    pub fn entrance_scan(&self) -> bool {
        self.entrance_scan
    }
    /// Choose the estimator of light leaving the volume: next-event
    /// estimation from scattering vertices (the default, smooth images) or
    /// splats at the boundary crossings (noisy; kept to check the default is
    /// unbiased). Smooth surfaces need the default.
    pub fn set_vertex_nee(&mut self, on: bool) {
        self.vertex_nee = on;
    }
    pub fn laser_mount(&self) -> f64 {
        self.laser_elevation
    }
    pub fn rig(&self) -> &RigTruth {
        &self.rig
    }
    pub fn quality(&self) -> &SimQuality {
        &self.quality
    }
    pub fn desc(&self) -> &SceneDesc {
        &self.desc
    }
    pub fn scene(&self) -> &Scene {
        &self.scene
    }
    /// Image size after binning.
    pub fn image_size(&self) -> (u32, u32) {
        let c = &self.rig.cameras[0];
        (
            c.width / self.quality.downscale,
            c.height / self.quality.downscale,
        )
    }

    /// The sensor of camera `k` (colour gains and response from the rig truth).
    pub fn sensor(&self, k: usize) -> Sensor {
        let c = &self.rig.cameras[k.min(self.rig.cameras.len() - 1)];
        Sensor {
            camera: k,
            colour_gain: c.colour_gain,
            response: c.response.clone(),
        }
    }

    /// Cameras of `mask` in the sample frame at turntable angle `turntable_rad`.
    pub fn splat_cameras(&self, turntable_rad: f64, mask: u8) -> Vec<(usize, SplatCamera)> {
        let to_sample = self.rig.world_to_sample(turntable_rad);
        let s = self.quality.downscale as f64;
        self.rig
            .cameras
            .iter()
            .enumerate()
            .filter(|(k, _)| *k < 8 && mask & (1 << k) != 0)
            .map(|(k, c)| {
                let pos = to_sample * c.position_vec();
                // camera-from-sample = camera-from-world * world-from-sample
                let rot: DMat3 = c.rotation_mat() * to_sample.transpose();
                let (fx, fy) = (c.focal_px[0] / s, c.focal_px[1] / s);
                let cam = SplatCamera {
                    id: k as u32,
                    pos: f32v(pos),
                    rot: rot.as_mat3(),
                    fx: fx as f32,
                    fy: fy as f32,
                    cx: (c.principal_px[0] / s) as f32,
                    cy: (c.principal_px[1] / s) as f32,
                    k1: c.k1 as f32,
                    k2: c.k2 as f32,
                    width: c.width / self.quality.downscale,
                    height: c.height / self.quality.downscale,
                    norm: (fx * fy / (450.0 * 450.0)) as f32,
                };
                (k, cam)
            })
            .collect()
    }

    /// Render one rig pose: per-camera linear radiance (W sr^-1 m^-2) for the
    /// cameras in `cameras_mask` (bit k = camera k). The same seed gives the
    /// same images for any number of threads.
    pub fn render_pose(
        &self,
        illum: &Illumination,
        cameras_mask: u8,
        seed: u64,
    ) -> Result<PoseRadiance, Error> {
        let finite = illum.turntable_rad.is_finite()
            && illum.light_arc_rad.is_finite()
            && illum.galvo_rad.is_finite();
        if !finite {
            return Err(Error::InvalidIllumination("angles must be finite".into()));
        }
        if let Some(l) = illum.laser {
            if l.channel > 2 {
                return Err(Error::InvalidIllumination(format!(
                    "laser channel {} (0 red, 1 green, 2 blue)",
                    l.channel
                )));
            }
            if !(l.power.is_finite() && (0.0..=1.0).contains(&l.power)) {
                return Err(Error::InvalidIllumination(format!(
                    "laser power {} not in [0, 1]",
                    l.power
                )));
            }
        }
        let cams = self.splat_cameras(illum.turntable_rad, cameras_mask);
        let splat: Vec<SplatCamera> = cams.iter().map(|(_, c)| c.clone()).collect();
        let to_sample = self.rig.world_to_sample(illum.turntable_rad);
        let (w, h) = self.image_size();
        let mut out: Vec<Option<RadianceImage>> = (0..8)
            .map(|k| {
                (cameras_mask & (1 << k) != 0 && k < self.rig.cameras.len())
                    .then(|| RadianceImage::black(w, h))
            })
            .collect();
        let mut tally = Tally::default();
        // One pass of `photons` from `source` lighting `fluxes` (channel,
        // W): one channel, or all three where they share the photons' paths
        // (`Accum::rgb`).
        let mut run = |source: Source,
                       fluxes: &[(usize, f64)],
                       photons: u64,
                       pass_seed: u64,
                       tally: &mut Tally| {
            if photons == 0 || fluxes.iter().all(|f| !(f.1 > 0.0)) {
                return;
            }
            let accum = if fluxes.len() == 3 {
                Accum::rgb(&splat)
            } else {
                Accum::new(&splat)
            };
            let pass = Pass {
                scene: &self.scene,
                cams: &splat,
                accum: Some(&accum),
                exits: None,
                channel: fluxes[0].0,
                vertex_nee: self.vertex_nee,
            };
            *tally = *tally + pass.run(&source, photons, pass_seed);
            for (plane, &(ch, flux_w)) in fluxes.iter().enumerate() {
                if !(flux_w > 0.0) {
                    continue;
                }
                // W per photon, mm^-2 -> m^-2
                let scale = flux_w / photons as f64 * 1e6;
                for (i, (k, cam)) in cams.iter().enumerate() {
                    if let Some(img) = out[*k].as_mut() {
                        for (px, v) in img.data.iter_mut().zip(accum.to_f64(i, plane, cam)) {
                            px[ch] += (v * scale) as f32;
                        }
                    }
                }
            }
        };
        if let Some(l) = illum.laser {
            let g =
                self.rig
                    .laser_geometry(self.laser_elevation, illum.light_arc_rad, illum.galvo_rad);
            let source = Source::Stripe {
                origin: f32v(to_sample * g.origin),
                centre: f32v(to_sample * g.centre),
                dir: f32v(to_sample * g.stripe_dir),
                length: g.length as f32,
            };
            let flux = self.rig.laser.power_w[l.channel] * l.power as f64;
            let photons = match self.quality.entrance_laser_photons {
                Some(n) if self.entrance_scan => n,
                _ => self.quality.laser_photons,
            };
            run(
                source,
                &[(l.channel, flux)],
                photons,
                seed ^ 0x004C_4153_4552,
                &mut tally,
            );
        }
        let hf = &self.scene.surface;
        let area_m2 = 4.0 * hf.half[0] as f64 * hf.half[1] as f64 * 1e-6;
        for k in 0..self.rig.lamps.len().min(8) {
            if illum.lamps & (1 << k) == 0 {
                continue;
            }
            let dir = to_sample * self.rig.lamp_direction(k, illum.light_arc_rad);
            if dir.z <= 1e-3 {
                continue; // grazing: no light on the sample
            }
            let fluxes =
                [0, 1, 2].map(|ch| (ch, self.rig.lamps[k].irradiance[ch] * dir.z * area_m2));
            let pass_seed = seed ^ ((k as u64 + 1) << 40) ^ 0x4C41_4D50;
            let source = Source::Lamp { to_lamp: f32v(dir) };
            if matches!(self.scene.kind, SurfaceKind::Lambertian(_)) {
                run(
                    source,
                    &fluxes,
                    self.quality.lamp_photons,
                    pass_seed,
                    &mut tally,
                );
            } else {
                for f in fluxes {
                    run(
                        source.clone(),
                        &[f],
                        self.quality.lamp_photons,
                        pass_seed,
                        &mut tally,
                    );
                }
            }
        }
        Ok(PoseRadiance { images: out, tally })
    }

    /// Trace photons from `source` in one channel without cameras, counting
    /// fates and (optionally) exit positions: for tests, profiles and the
    /// benchmark. Coordinates in the sample frame.
    pub fn trace(
        &self,
        source: &Source,
        channel: usize,
        photons: u64,
        seed: u64,
        exits: Option<&ExitGrid>,
    ) -> Tally {
        self.trace_with(source, channel, photons, seed, exits, true)
    }

    /// `trace` with the walk chosen: `wide` where it applies (as `trace`),
    /// or every photon through the scalar walk (for comparisons).
    pub(crate) fn trace_with(
        &self,
        source: &Source,
        channel: usize,
        photons: u64,
        seed: u64,
        exits: Option<&ExitGrid>,
        wide: bool,
    ) -> Tally {
        let pass = Pass {
            scene: &self.scene,
            cams: &[],
            accum: None,
            exits,
            channel: channel.min(2),
            vertex_nee: false,
        };
        pass.run_with(source, photons, seed, wide)
    }
}
