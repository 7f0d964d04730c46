//! `[[medium]]` tables: homogeneous boxes, grids from files and procedural noise.
use super::*;

pub(super) enum Medium {
    Homogeneous(MediumDesc),
    Grid(GridMedium),
}

pub(super) fn medium(
    ck: &Check,
    dir: &Path,
    i: usize,
    m: &FileMedium,
    cache: &mut AssetCache,
) -> Result<Medium> {
    let g = |phase: &Option<FilePhase>| match phase {
        None | Some(FilePhase::Isotropic) => None,
        Some(FilePhase::Hg { g }) => Some(*g),
    };
    match m {
        FileMedium::Grid {
            path,
            grid,
            density_scale,
            albedo,
            phase,
            transform,
        } => {
            let spec = MediumSpec {
                density_scale: Some(*density_scale),
                albedo: Some(*albedo),
                g: g(phase),
                transform: transform.as_ref().map(|t| TransformSpec::Srt {
                    translate: t.translate,
                    rotate_deg: t.rotate_deg,
                    scale: t.scale,
                }),
                ..Default::default()
            };
            let name = grid.as_deref().unwrap_or("density");
            grid_medium(ck, i, &dir.join(path), name, spec, cache).map(Medium::Grid)
        }
        FileMedium::Homogeneous {
            bounds,
            sigma_t,
            albedo,
            phase,
        } => {
            let mp = MediumSpec {
                sigma_t: Some(*sigma_t),
                albedo: Some(*albedo),
                g: g(phase),
                ..Default::default()
            }
            .check(ck.path, toml_field(i))?;
            Ok(Medium::Homogeneous(MediumDesc {
                bounds: check_bounds(ck, &format!("medium[{i}].bounds"), bounds)?,
                sigma_t: mp.sigma_t,
                albedo: mp.albedo,
                phase: mp.phase,
            }))
        }
        FileMedium::Noise {
            preset,
            bounds,
            seed,
            octaves,
            frequency,
            resolution,
            density_scale,
            albedo,
            phase,
        } => {
            let params = NoiseParams {
                preset: noise_preset(ck, i, preset)?,
                bounds: check_bounds(ck, &format!("medium[{i}].bounds"), bounds)?,
                seed: seed.unwrap_or(1),
                octaves: octaves.unwrap_or(6),
                frequency: frequency.unwrap_or(2.0),
                resolution: resolution.unwrap_or(DEFAULT_RESOLUTION),
            };
            let spec = MediumSpec {
                density_scale: Some(*density_scale),
                albedo: Some(*albedo),
                g: g(phase),
                ..Default::default()
            };
            noise_medium(ck, i, params, spec, cache).map(Medium::Grid)
        }
    }
}

/// A grid medium from grid `name` of the file at `p` (read once: hashed and parsed from
/// the same bytes).
pub(super) fn grid_medium(
    ck: &Check,
    i: usize,
    p: &Path,
    name: &str,
    spec: MediumSpec,
    cache: &mut AssetCache,
) -> Result<GridMedium> {
    let mp = spec.check(ck.path, toml_field(i))?;
    Format::of_kind(p, &Format::GRIDS)
        .map_err(|e| ck.err(&format!("medium[{i}].path"), e.to_string()))?;
    let (loaded, mut h) =
        cache.grid_file(p, name, |bytes| GridFile::from_bytes(p, bytes)?.load(name))?;
    let (scale, xf) = (mp.density_scale, mp.transform);
    h.update(format!("{name} {scale} {xf:?}").as_bytes());
    Ok(GridMedium::new(
        loaded,
        xf,
        scale,
        mp.albedo,
        mp.phase,
        format!("{} [{name}]", p.display()),
        *h.finalize().as_bytes(),
    ))
}

pub(super) fn noise_preset(ck: &Check, i: usize, preset: &str) -> Result<Preset> {
    match preset {
        "cloud" => Ok(Preset::Cloud),
        "smoke" => Ok(Preset::Smoke),
        "fog" => Ok(Preset::Fog),
        other => Err(ck.err(
            &format!("medium[{i}].preset"),
            format!("expected cloud, smoke or fog, got \"{other}\""),
        )),
    }
}

/// A procedural noise medium (its grid built once per parameter set and kept).
pub(super) fn noise_medium(
    ck: &Check,
    i: usize,
    params: NoiseParams,
    spec: MediumSpec,
    cache: &mut AssetCache,
) -> Result<GridMedium> {
    let f = |k: &str| format!("medium[{i}].{k}");
    if !(1..=12).contains(&params.octaves) {
        return Err(ck.err(
            &f("octaves"),
            format!("expected 1..=12, got {}", params.octaves),
        ));
    }
    if !(params.frequency.is_finite() && params.frequency > 0.0) {
        return Err(ck.err(&f("frequency"), "expected a finite number > 0".into()));
    }
    if !(2..=1024).contains(&params.resolution) {
        return Err(ck.err(
            &f("resolution"),
            format!("expected 2..=1024 voxels, got {}", params.resolution),
        ));
    }
    let mp = spec.check(ck.path, toml_field(i))?;
    let scale = mp.density_scale;
    let hash = blake3::hash(format!("noise {params:?} {scale}").as_bytes());
    let key = format!("noise {params:?}");
    let field_hash = *blake3::hash(key.as_bytes()).as_bytes();
    let grid = cache.grid(&key, field_hash, || Ok(procedural::build(&params)))?;
    Ok(GridMedium::new(
        grid,
        DAffine3::IDENTITY,
        scale,
        mp.albedo,
        mp.phase,
        format!("noise {:?} seed {}", params.preset, params.seed),
        *hash.as_bytes(),
    ))
}
