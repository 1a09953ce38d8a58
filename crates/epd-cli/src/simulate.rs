//! `epd simulate`: frames of tof-sim (`tof_sim::settings`) written as PLY with their
//! ground truth as JSON.

use std::process::ExitCode;

use anyhow::Context;
use indicatif::ProgressBar;

use crate::args::{NoiseArg, PlyArg, PrecisionArg, SensorArg, SimulateArgs};
use crate::usage;

pub fn run_simulate(a: &SimulateArgs) -> anyhow::Result<ExitCode> {
    use epd_io::ply::{PlyFormat, PlyPrecision};
    use tof_sim::NoiseModel;
    use tof_sim::settings::{Feature, PoseOverride, SimulateError, SimulateSettings, Simulator};
    let (out, frames) = (a.out.clone(), a.frames);
    let format = match a.ply {
        PlyArg::Binary => PlyFormat::BinaryLittleEndian,
        PlyArg::Ascii => PlyFormat::Ascii,
    };
    let precision = match a.precision {
        PrecisionArg::F64 => PlyPrecision::F64,
        PrecisionArg::F32 => PlyPrecision::F32,
    };
    let sim = Simulator::new(&SimulateSettings {
        seed: a.seed,
        sigma: a.sigma,
        od_in: a.od_in,
        ovality: a.ovality,
        wall_mm: a.wall_mm,
        points: a.points,
        outliers: a.outliers,
        noise: match a.noise {
            NoiseArg::Range => NoiseModel::Range,
            NoiseArg::Isotropic => NoiseModel::Isotropic,
        },
        helios2: a.sensor == SensorArg::Helios2,
        pose: PoseOverride::default(),
        feature: match (a.bend_at, a.tee_at) {
            (Some(m), _) => Some(Feature::BendAt(m)),
            (None, Some(m)) => Some(Feature::TeeAt(m)),
            (None, None) => None,
        },
    })
    .map_err(|e| match e {
        SimulateError::Setting(m) => usage(m),
        SimulateError::Sim(e) => e.into(),
    })?;
    check_out_folder(&out)?;
    std::fs::create_dir_all(&out).with_context(|| format!("cannot create {}", out.display()))?;
    let mut frame = tof_sim::Frame::empty();
    let bar = ProgressBar::new(frames);
    for k in 0..frames {
        sim.frame(k, &mut frame)?;
        if frame.is_empty() {
            // Settings whose rays all miss the wall or leave the range (a noise or a pipe
            // far beyond any camera's): a frame of no point is nothing to write.
            let short = |v: f64| {
                if (1e-3..1e6).contains(&v.abs()) {
                    format!("{v}")
                } else {
                    format!("{v:e}")
                }
            };
            return Err(usage(format!(
                "frame {k}: no point (no ray meets the wall within the camera's range with \
                 these settings: --od-in {} in, --sigma {} m); check them",
                short(a.od_in),
                short(a.sigma)
            )));
        }
        let stem = format!("frame_{k:04}");
        epd_io::ply::save(
            &out.join(format!("{stem}.ply")),
            &frame.cloud(),
            format,
            precision,
        )?;
        let json = format!("{}\n", epd_io::json::object(&sim.truth(k, &frame)));
        epd_io::atomic::write_bytes_atomic(&out.join(format!("{stem}.json")), json.as_bytes())?;
        if k == 0 && frames > 1 {
            check_room(&out, frames, &stem)?;
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    epd_io::stderr_line!(
        "{frames} frames written to {} (PLY + ground-truth JSON)",
        epd_io::name::shown(&out)
    );
    Ok(ExitCode::SUCCESS)
}

/// After the first frame: the frames asked for fit in the free space of `out`'s disk, each
/// the size of the first (its PLY and JSON), else a usage error naming both before the
/// disk fills (`--frames 10^12` had written until it did).
fn check_room(out: &std::path::Path, frames: u64, stem: &str) -> anyhow::Result<()> {
    let size = |ext: &str| {
        std::fs::metadata(out.join(format!("{stem}.{ext}")))
            .map(|m| m.len())
            .unwrap_or(0)
    };
    let per_frame = size("ply") + size("json");
    let Some(free) = free_bytes(out) else {
        return Ok(());
    };
    let need = u128::from(per_frame) * u128::from(frames - 1);
    if need > u128::from(free) {
        return Err(usage(format!(
            "--frames {frames}: about {:.3e} bytes more ({per_frame} per frame), and {} has \
             {free} bytes free; ask for fewer frames or another --out",
            need as f64,
            epd_io::name::shown(out)
        )));
    }
    Ok(())
}

/// The bytes an unprivileged user may still write on the disk of `dir` (statvfs);
/// `None` when the system does not say.
#[cfg(unix)]
fn free_bytes(dir: &std::path::Path) -> Option<u64> {
    use std::os::unix::ffi::OsStrExt;
    let c = std::ffi::CString::new(dir.as_os_str().as_bytes()).ok()?;
    let mut st: libc::statvfs = unsafe { std::mem::zeroed() };
    // SAFETY: `c` is a NUL-terminated path and `st` a writable statvfs.
    let rc = unsafe { libc::statvfs(c.as_ptr(), &mut st) };
    (rc == 0).then(|| (st.f_bavail as u64).saturating_mul(st.f_frsize as u64))
}

#[cfg(not(unix))]
fn free_bytes(_: &std::path::Path) -> Option<u64> {
    None
}

/// `--out` names a folder, or nothing yet (it is created): a usage error (exit 2) naming
/// what is there instead — a file, or a symbolic link to something missing (which
/// `create_dir_all` reports as "File exists").
pub(crate) fn check_out_folder(out: &std::path::Path) -> anyhow::Result<()> {
    let Ok(link) = std::fs::symlink_metadata(out) else {
        return Ok(());
    };
    let name = out.display();
    match std::fs::metadata(out) {
        Ok(m) if m.is_dir() => Ok(()),
        Ok(_) => Err(usage(format!(
            "--out {name}: exists and is not a folder; give a folder (it is created if missing)"
        ))),
        Err(_) if link.file_type().is_symlink() => {
            let target = std::fs::read_link(out)
                .map(|t| t.display().to_string())
                .unwrap_or_else(|_| "?".into());
            Err(usage(format!(
                "--out {name}: a symbolic link to {target}, which does not exist; create that \
                 folder or give another --out"
            )))
        }
        Err(e) => Err(usage(format!("--out {name}: {e}"))),
    }
}
