//! Measures the trainer's tuning knobs: every variant (a set of `TrainOptions` changes) is encoded
//! on every material and profile and compared with the defaults at the same rate (the knobs do not
//! change the layout, so the rate is the same) — whole-chain PSNR as `nmat eval` measures it.
//!
//! Usage: nmat-sweep [--profile P]... [--threads N] [--csv PATH] [--variant NAME=K=V[,K=V]...]...
//!                   MATERIAL_DIR...
//! The defaults (variant `default`) always run. Rows go to stdout and, with `--csv`, are appended
//! to PATH; rows already in PATH are not measured again, so a sweep can be resumed. A summary per
//! variant (mean ΔPSNR against `default`, wins, losses, mean seconds) follows on stdout.
//! Knobs: steps, batch, lr_mlp, lr_latents, joint_percent, qat_percent, qat_lr, qat_lr_latents,
//! int8_percent, mip_uniform_share, error_share, latent_init_spread, output_margin (docs/ENCODING.md,
//! "Tuning").

use nmat_encode::texset::{self, LoadOptions};
use nmat_encode::{EncodeOptions, Profile, TrainOptions, encode};
use std::collections::BTreeMap;
use std::io::Write;
use std::path::PathBuf;
use std::time::Instant;

type Result<T> = std::result::Result<T, String>;

const KNOBS: &str = "steps, batch, lr_mlp, lr_latents, joint_percent, qat_percent, qat_lr, qat_lr_latents, int8_percent, \
                     mip_uniform_share, error_share, latent_init_spread, output_margin";

/// Applies `key=value` to `o`.
fn set_knob(o: &mut TrainOptions, key: &str, value: &str) -> Result<()> {
    let bad = |e: &dyn std::fmt::Display| format!("--variant: {key}={value}: {e}");
    let int = || value.parse::<usize>().map_err(|e| bad(&e));
    let float = || value.parse::<f32>().map_err(|e| bad(&e));
    match key {
        "steps" => o.steps = int()?.max(1),
        "batch" => o.batch = int()?.max(1),
        "lr_mlp" => o.lr_mlp = float()?,
        "lr_latents" => o.lr_latents = float()?,
        "joint_percent" => o.joint_percent = int()? as u32,
        "qat_percent" => o.qat_percent = int()? as u32,
        "int8_percent" => o.int8_percent = int()? as u32,
        "qat_lr" => o.qat_lr = float()?,
        "qat_lr_latents" => o.qat_lr_latents = float()?,
        "mip_uniform_share" => o.mip_uniform_share = float()?,
        "error_share" => o.error_share = float()?,
        "latent_init_spread" => o.latent_init_spread = float()?,
        "output_margin" => o.output_margin = Some(float()?),
        _ => return Err(format!("--variant: unknown knob {key:?}; knobs: {KNOBS}")),
    }
    Ok(())
}

/// `NAME=K=V,K=V` → (NAME, options).
fn parse_variant(spec: &str) -> Result<(String, TrainOptions)> {
    let (name, knobs) = spec
        .split_once('=')
        .ok_or_else(|| format!("--variant {spec}: expected NAME=KNOB=VALUE[,KNOB=VALUE]..."))?;
    if name.is_empty() || name.contains(',') || name == "default" {
        return Err(format!("--variant {spec}: give the variant a name other than 'default'"));
    }
    let mut o = TrainOptions::default();
    for kv in knobs.split(',') {
        let (k, v) =
            kv.split_once('=').ok_or_else(|| format!("--variant {spec}: {kv:?} is not K=V"))?;
        set_knob(&mut o, k.trim(), v.trim())?;
    }
    Ok((name.to_string(), o))
}

struct Args {
    profiles: Vec<Profile>,
    threads: Option<usize>,
    csv: Option<PathBuf>,
    variants: Vec<(String, TrainOptions)>,
    materials: Vec<PathBuf>,
}

const USAGE: &str = "usage: nmat-sweep [--profile P]... [--threads N] [--csv PATH] \
                     [--variant NAME=KNOB=VALUE[,KNOB=VALUE]...]... MATERIAL_DIR...";

fn parse_args() -> Result<Args> {
    let mut a = Args {
        profiles: Vec::new(),
        threads: None,
        csv: None,
        variants: vec![("default".into(), TrainOptions::default())],
        materials: Vec::new(),
    };
    let mut it = std::env::args().skip(1);
    while let Some(arg) = it.next() {
        let mut value = |flag: &str| it.next().ok_or_else(|| format!("{flag} needs a value"));
        match arg.as_str() {
            "--profile" => {
                let v = value("--profile")?;
                a.profiles
                    .push(Profile::by_name(&v).ok_or_else(|| format!("--profile {v}: unknown"))?);
            }
            "--threads" => {
                let v = value("--threads")?;
                let n = v.parse().map_err(|e| format!("--threads {v}: {e}"))?;
                a.threads = Some(n);
            }
            "--csv" => a.csv = Some(value("--csv")?.into()),
            "--variant" => a.variants.push(parse_variant(&value("--variant")?)?),
            "--help" | "-h" => {
                println!("{USAGE}\nknobs: {KNOBS}");
                std::process::exit(0);
            }
            s if s.starts_with("--") => return Err(format!("unknown option {s}")),
            _ => a.materials.push(arg.into()),
        }
    }
    if a.materials.is_empty() {
        return Err(USAGE.into());
    }
    if a.profiles.is_empty() {
        a.profiles.push(Profile::by_name(nmat_encode::DEFAULT_PROFILE).expect("default profile"));
    }
    Ok(a)
}

/// One measured row.
struct Row {
    material: String,
    profile: String,
    variant: String,
    bppc: f64,
    psnr: f64,
    seconds: f64,
}

impl Row {
    fn key(&self) -> (String, String, String) {
        (self.material.clone(), self.profile.clone(), self.variant.clone())
    }
    fn csv(&self) -> String {
        format!(
            "{},{},{},{:.4},{:.3},{:.1}",
            self.material, self.profile, self.variant, self.bppc, self.psnr, self.seconds
        )
    }
    fn parse(line: &str) -> Option<Row> {
        let f: Vec<&str> = line.split(',').collect();
        let [m, p, v, b, q, s] = f.as_slice() else { return None };
        Some(Row {
            material: m.to_string(),
            profile: p.to_string(),
            variant: v.to_string(),
            bppc: b.parse().ok()?,
            psnr: q.parse().ok()?,
            seconds: s.parse().ok()?,
        })
    }
}

const HEADER: &str = "material,profile,variant,bppc,psnr_db,seconds";

fn run() -> Result<()> {
    let a = parse_args()?;
    if let Some(n) = a.threads {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build_global()
            .map_err(|e| format!("--threads {n}: {e}"))?;
    }
    let mut done: BTreeMap<(String, String, String), Row> = BTreeMap::new();
    if let Some(path) = &a.csv
        && let Ok(text) = std::fs::read_to_string(path)
    {
        for r in text.lines().filter_map(Row::parse) {
            done.insert(r.key(), r);
        }
    }
    let mut out = match &a.csv {
        Some(path) => {
            let fresh = !path.exists();
            let mut f = std::fs::OpenOptions::new()
                .create(true)
                .append(true)
                .open(path)
                .map_err(|e| format!("--csv {}: {e}", path.display()))?;
            if fresh {
                writeln!(f, "{HEADER}").map_err(|e| format!("--csv {}: {e}", path.display()))?;
            }
            Some(f)
        }
        None => None,
    };
    println!("{HEADER}");
    for dir in &a.materials {
        let name = dir.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        let load = || -> std::result::Result<_, nmat_encode::EncodeError> {
            let files = texset::collect_inputs(std::slice::from_ref(dir))?;
            let roles = texset::assign_roles(&files, &[])?;
            texset::load(&roles, &LoadOptions::default())
        };
        let set = load().map_err(|e| format!("{}: {e}", dir.display()))?;
        for profile in &a.profiles {
            for (variant, train) in &a.variants {
                let key = (name.clone(), profile.name().to_string(), variant.clone());
                if let Some(r) = done.get(&key) {
                    println!("{}", r.csv());
                    continue;
                }
                let options =
                    EncodeOptions { profile: *profile, train: train.clone(), ..Default::default() };
                let t = Instant::now();
                let enc = encode(&set, &options, &mut |_| {})
                    .map_err(|e| format!("{}: {}: {e}", dir.display(), profile.name()))?;
                let row = Row {
                    material: key.0.clone(),
                    profile: key.1.clone(),
                    variant: key.2.clone(),
                    bppc: enc.quality.bppc,
                    psnr: enc.quality.psnr,
                    seconds: t.elapsed().as_secs_f64(),
                };
                println!("{}", row.csv());
                if let Some(f) = out.as_mut() {
                    writeln!(f, "{}", row.csv()).map_err(|e| format!("--csv: {e}"))?;
                }
                done.insert(key, row);
            }
        }
    }
    summary(&a, &done);
    Ok(())
}

/// Per variant and profile: mean ΔPSNR against `default` on the same material, wins, losses.
fn summary(a: &Args, rows: &BTreeMap<(String, String, String), Row>) {
    println!();
    println!("| variant | profile | materials | mean ΔPSNR dB | wins | losses | mean seconds |");
    println!("|---|---|---:|---:|---:|---:|---:|");
    for profile in &a.profiles {
        let p = profile.name().to_string();
        for (variant, _) in &a.variants {
            let (mut n, mut sum, mut wins, mut losses, mut secs) = (0, 0.0, 0, 0, 0.0);
            for r in rows.values().filter(|r| r.profile == p && &r.variant == variant) {
                let base = rows.get(&(r.material.clone(), p.clone(), "default".into()));
                let Some(base) = base else { continue };
                let d = r.psnr - base.psnr;
                n += 1;
                sum += d;
                secs += r.seconds;
                wins += usize::from(d > 0.0);
                losses += usize::from(d < 0.0);
            }
            if n > 0 {
                let mean = sum / n as f64;
                let s = secs / n as f64;
                println!("| {variant} | {p} | {n} | {mean:+.2} | {wins} | {losses} | {s:.0} |");
            }
        }
    }
}

fn main() {
    if let Err(e) = run() {
        eprintln!("nmat-sweep: {e}");
        std::process::exit(2);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn variants_set_their_knobs_and_bad_ones_are_named() {
        let (name, o) = parse_variant("fast-lr=steps=5,lr_mlp=0.5, qat_percent = 7").unwrap();
        assert_eq!(name, "fast-lr");
        assert_eq!((o.steps, o.lr_mlp, o.qat_percent), (5, 0.5, 7));
        assert_eq!(o.batch, TrainOptions::default().batch, "untouched knobs keep their default");
        for (spec, says) in [
            ("x=speed=3", "unknown knob \"speed\""),
            ("x=steps=many", "steps=many"),
            ("default=steps=3", "other than 'default'"),
            ("x", "expected NAME=KNOB=VALUE"),
            ("x=steps", "is not K=V"),
        ] {
            let e = parse_variant(spec).unwrap_err();
            assert!(e.contains(says), "{spec}: {e}");
        }
    }

    #[test]
    fn rows_read_back_what_they_write() {
        let r = Row {
            material: "rock".into(),
            profile: "ntc-0.2".into(),
            variant: "steps-x2".into(),
            bppc: 0.19987,
            psnr: 31.0612,
            seconds: 88.04,
        };
        let back = Row::parse(&r.csv()).unwrap();
        assert_eq!(back.key(), r.key());
        assert_eq!((back.bppc, back.psnr, back.seconds), (0.1999, 31.061, 88.0));
        assert!(Row::parse(HEADER).is_none());
    }
}
