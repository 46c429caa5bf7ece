//! `nmat encode`: maps → .nmat, neural (a profile, a rate or a PSNR target) or indexed JPEG.

use crate::args::{Address, CodecArg, EffortArg, EncodeArgs, OnOffArg, SubsamplingArg};
use crate::common::{Result, encode_with_progress, profile_named, threads, train_options};
use nmat_cli::output;
use nmat_core::AddressMode;
use nmat_encode::texset::TextureSet;
use nmat_encode::texset::{self, LoadOptions};
use nmat_encode::{
    EncodeError, EncodeOption, EncodeOptions, Encoded, LayoutChoice, LayoutTrial, PROFILES,
    Profile, Storage, TrainOptions,
};
use std::path::{Path, PathBuf};
use std::time::Instant;

pub fn run(args: EncodeArgs) -> Result<()> {
    threads(args.train.threads)?;
    let explicit = args
        .maps
        .iter()
        .map(|m| texset::parse_map_argument(m))
        .collect::<std::result::Result<Vec<_>, _>>()?;
    let files = texset::collect_inputs(&args.inputs)?;
    if files.is_empty() && explicit.is_empty() {
        return Err("no input maps: pass a folder, files, or --map ROLE=PATH".into());
    }
    let roles = texset::assign_roles(&files, &explicit)?;
    if !args.dry_run {
        let inputs: Vec<PathBuf> = roles.iter().map(|(_, p)| p.clone()).collect();
        output::check_output(&args.output, &inputs)?;
    }
    let max_memory = args.max_memory.unwrap_or(texset::DEFAULT_MAX_MEMORY);
    let set = texset::load(&roles, &LoadOptions { resize: args.resize, max_memory })?;
    let address_mode = match args.address {
        Address::Wrap => AddressMode::Wrap,
        Address::Clamp => AddressMode::Clamp,
    };
    if args.codec == CodecArg::Jpeg {
        return encode_jpeg(&args, &set, address_mode);
    }
    if let Some(q) = args.quality {
        return Err(Box::new(EncodeError::BadOption {
            option: EncodeOption::Quality,
            value: q.to_string(),
            reason: "sets the JPEG codec's quality; pass --codec jpeg (neural rates are \
                     --profile, --bppc or --target-psnr)",
        }));
    }
    if args.subsampling.is_some() {
        return Err("--subsampling belongs to the JPEG codec; pass --codec jpeg".into());
    }
    let train = TrainOptions {
        output_margin: args.output_margin,
        ..train_options(&args.train, nmat_encode::DEFAULT_STEPS)?
    };
    // `encode` checks it too, but `--dry-run` trains nothing: refuse a bad margin either way.
    if let Some(margin) = args.output_margin {
        nmat_encode::check_output_margin(margin)?;
    }
    let storage = if args.fixed_rate { Storage::FixedRate } else { Storage::Packed };
    let memory_factor = args.memory_factor.unwrap_or(nmat_encode::DEFAULT_MEMORY_FACTOR);
    // Everything but the profile, which the arguments or the target search choose.
    let base = EncodeOptions {
        train,
        address_mode,
        storage,
        memory_factor,
        legacy_lod: args.legacy_lod,
        layout: args.layout.map_or(LayoutChoice::default(), Into::into),
        polish_sweeps: args.polish_sweeps,
        ..EncodeOptions::default()
    };
    let start = Instant::now();
    let hi_bilinear = args.hi_bilinear.map(|v| v == OnOffArg::On);
    let encoded = if let Some(target) = args.target_psnr {
        search_target(&set, target, &base, hi_bilinear)?
    } else {
        let profile = match (&args.profile, args.bppc) {
            (Some(name), _) => profile_named(name)?,
            (None, Some(b)) if b.is_finite() && b > 0.0 => Profile::nearest(b),
            (None, Some(b)) => {
                return Err(Box::new(EncodeError::BadOption {
                    option: EncodeOption::Bppc,
                    value: b.to_string(),
                    reason: "must be a positive number",
                }));
            }
            (None, None) => profile_named(nmat_encode::DEFAULT_PROFILE)?,
        };
        let profile = match hi_bilinear {
            None => profile,
            Some(on) => profile.with_hi_bilinear(on).ok_or_else(|| {
                format!(
                    "--hi-bilinear belongs to the NTC profiles; {} is an NBC profile (no \
                     high-resolution grid)",
                    profile.name()
                )
            })?,
        };
        if args.dry_run {
            print!("{}", plan(&set, profile, storage, memory_factor, base.layout)?);
            return Ok(());
        }
        encode_with_progress(&set, &EncodeOptions { profile, ..base })?
    };
    if let Some(note) = rate_note(&encoded) {
        eprintln!("{note}");
    }
    if let Some(t) = encoded.trial {
        println!("{}", trial_line(&t));
    }
    write_encoded(&args.output, encoded.file(), start)?;
    if let Some(packed) = &encoded.packed {
        println!(
            "latents entropy-coded: {} bytes on disk, {} in memory (fixed-rate; {:.3} of that)",
            packed.len(),
            encoded.bytes.len(),
            packed.len() as f64 / encoded.bytes.len() as f64
        );
    }
    print!(
        "{}",
        output::quality_table(
            &set,
            &encoded.quality,
            Some(&format!("profile {}", encoded.config.profile)),
        )
    );
    Ok(())
}

/// Writes an encoded file atomically and says so, with the time since `start`.
fn write_encoded(path: &Path, bytes: &[u8], start: Instant) -> Result<()> {
    output::write_atomic(path, bytes)?;
    let seconds = start.elapsed().as_secs_f64();
    println!("wrote {} ({} bytes) in {seconds:.1} s", path.display(), bytes.len());
    Ok(())
}

/// `nmat encode --codec jpeg`: at `--quality` or the highest quality within `--bppc`.
fn encode_jpeg(args: &EncodeArgs, set: &TextureSet, address_mode: AddressMode) -> Result<()> {
    use nmat_encode::jpeg::{JpegOptions, Subsampling};
    let neural_only = [
        ("--profile", args.profile.is_some()),
        ("--target-psnr", args.target_psnr.is_some()),
        ("--dry-run", args.dry_run),
        ("--memory-factor", args.memory_factor.is_some()),
        ("--legacy-lod", args.legacy_lod),
        ("--layout", args.layout.is_some()),
        ("--hi-bilinear", args.hi_bilinear.is_some()),
        ("--output-margin", args.output_margin.is_some()),
        ("--polish-sweeps", args.polish_sweeps.is_some()),
        ("--steps", args.train.steps.is_some()),
        ("--effort", args.train.effort != EffortArg::Default),
        ("--seed", args.train.seed != TrainOptions::default().seed),
    ];
    if let Some((option, _)) = neural_only.iter().find(|(_, given)| *given) {
        return Err(format!(
            "{option} belongs to the neural codec; --codec jpeg takes --quality or --bppc"
        )
        .into());
    }
    let subsampling = match args.subsampling {
        None | Some(SubsamplingArg::S420) => Subsampling::S420,
        Some(SubsamplingArg::S422) => Subsampling::S422,
        Some(SubsamplingArg::S444) => Subsampling::S444,
    };
    let quality = args.quality.unwrap_or(nmat_encode::jpeg::DEFAULT_QUALITY);
    let storage = if args.fixed_rate { Storage::FixedRate } else { Storage::Packed };
    let options = JpegOptions { quality, subsampling, address_mode, storage };
    let start = Instant::now();
    let encoded = match args.bppc {
        Some(bppc) => nmat_encode::jpeg::encode_jpeg_to_rate(set, bppc, &options)?,
        None => nmat_encode::jpeg::encode_jpeg(set, &options)?,
    };
    if let Some(bppc) = args.bppc.filter(|&b| encoded.quality.bppc > b) {
        let why = if encoded.packed.is_some() {
            "the streams' headers and tables alone take that"
        } else {
            "the MCU index and DC values of a fixed-rate file alone cost 0.21 bits per pixel of a \
             4:2:0 map and 0.47 of a gray one"
        };
        eprintln!(
            "note: {:.3} BPPC at quality 1 is above --bppc {bppc}: {why}",
            encoded.quality.bppc
        );
    }
    write_encoded(&args.output, encoded.file(), start)?;
    if let Some(packed) = &encoded.packed {
        println!(
            "streams stored without their index: {} bytes on disk, {} in memory (index rebuilt \
             when opened; {:.3} of that)",
            packed.len(),
            encoded.bytes.len(),
            packed.len() as f64 / encoded.bytes.len() as f64
        );
    }
    let maps = nmat_encode::jpeg::plan_maps(set, subsampling);
    let setting = format!("jpeg quality {} ({} JPEG maps)", encoded.jpeg_quality, maps.len());
    print!("{}", output::quality_table(set, &encoded.quality, Some(&setting)));
    Ok(())
}

/// What `encode --dry-run` prints: the solved layout of `profile` for `set` that `choice` trains
/// (bits first for a trial) and its byte budget, then the other way where there are two.
fn plan(
    set: &TextureSet,
    profile: Profile,
    storage: Storage,
    memory_factor: f64,
    choice: LayoutChoice,
) -> Result<String> {
    let shape = nmat_encode::shape_of(set);
    let layouts = nmat_encode::layouts(profile, &shape, storage, memory_factor)?;
    // `layouts` lists the grids' resolution first, then (where it differs) one more bit first.
    let shown = if choice == LayoutChoice::ResolutionFirst { 0 } else { layouts.len() - 1 };
    let layout = &layouts[shown];
    let cfg = &layout.config;
    let budget = cfg.byte_budget(&shape);
    // BPPC's denominator: width · height · channels that vary, of mip 0.
    let texel_channels = shape.budget_bits(1.0);
    let rate = |bytes: f64| bytes * 8.0 / texel_channels;
    let mut s = format!(
        "{}: {}×{}, {} channels ({} learned), nominal {} BPPC\n",
        profile.name(),
        set.width,
        set.height,
        set.channel_count(),
        shape.learned,
        profile.bppc(),
    );
    let fixed = budget.total() as f64;
    match layout.latent_bytes {
        Some(latents) => s.push_str(&format!(
            "packed: latents trained to code in {latents:.0} bytes, the file {:.4} BPPC on disk; \
             in memory {:.4} BPPC ({memory_factor} × nominal at most)\n",
            rate(fixed - budget.latents as f64 + 8.0 + latents),
            rate(fixed)
        )),
        None => s.push_str(&format!(
            "this file {:.4} BPPC ({:+.1} %){}\n",
            rate(fixed),
            100.0 * (fixed * 8.0 / shape.budget_bits(profile.bppc()) - 1.0),
            if storage == Storage::Packed { ", less on disk once packed" } else { "" }
        )),
    }
    s.push_str(&output::map_lines(&set.maps));
    s.push_str(&format!(
        "\nnetwork {} → {:?} → {}\n",
        cfg.input_width(),
        cfg.hidden,
        set.channel_count()
    ));
    s.push_str(&grid_lines(cfg));
    s.push_str(&level_lines(cfg));
    s.push_str(&output::budget_table(&budget, texel_channels));
    if layouts.len() > 1 {
        let (other, way, arg) = match shown {
            0 => (&layouts[1], "one more bit per latent first", "bits-first"),
            _ => (&layouts[0], "the grids' resolution first", "resolution-first"),
        };
        s.push_str(&format!(
            "\nor, {way} (--layout {arg}; --layout trial trains both for a quarter of the steps \
             and keeps the better; this one is {:.4} BPPC in memory):\n",
            rate(other.config.byte_budget(&shape).total() as f64)
        ));
        s.push_str(&grid_lines(&other.config));
        if other.config.levels != cfg.levels {
            s.push_str(&level_lines(&other.config));
        }
    }
    Ok(s)
}

/// A line per latent grid of `cfg`: resolution, channels, bits and bytes.
fn grid_lines(cfg: &nmat_encode::ModelConfig) -> String {
    let mut s = String::new();
    for (i, g) in cfg.grids.iter().enumerate() {
        s.push_str(&format!(
            "  grid {i:2} {:5}×{:<5} {:2} channels × {} bits  {:8} bytes\n",
            g.width,
            g.height,
            g.channels,
            g.bits,
            4 * g.bits().div_ceil(32)
        ));
    }
    s
}

/// A line per level of `cfg`: its mips and the terms that read its grids, as `nmat info` lists
/// them.
fn level_lines(cfg: &nmat_encode::ModelConfig) -> String {
    let mut s = String::new();
    for (l, terms) in cfg.levels.iter().enumerate() {
        let mips = (0u32..).zip(&cfg.mip_to_level).filter(|&(_, &level)| usize::from(level) == l);
        let terms = terms.iter().map(|t| format!("{:?}{:?}", t.mode, t.grids.as_slice()));
        s.push_str(&output::level_line(l, mips.map(|(k, _)| k), terms));
    }
    s
}

/// What `encode` says of a layout trial: each way's whole-chain PSNR and the one kept.
fn trial_line(t: &LayoutTrial) -> String {
    let kept = match t.chosen() {
        LayoutChoice::BitsFirst => "one more bit per latent",
        _ => "the grids' resolution",
    };
    format!(
        "layout trial (a quarter of the steps each): the grids' resolution first {:.2} dB, one \
         more bit per latent first {:.2} dB; kept {kept} first",
        t.resolution_first_db, t.bits_first_db
    )
}

/// A note when the file lands more than 5 % away from its profile's nominal rate (on disk; a
/// fixed-rate file's layout is solved for it, a packed file's latents are trained to it): the
/// material is too small for the rate (the smallest network and grids exceed it), the layout's
/// largest grids fall short of it, or a packed file's latents code smaller than it.
fn rate_note(e: &Encoded) -> Option<String> {
    let nominal = Profile::by_name(e.config.profile)?.bppc();
    let packed = e.packed.is_some();
    let off = e.quality.bppc / nominal - 1.0;
    let why = if off > 0.0 {
        "the material is too small for that rate: its smallest network and grids are this file"
    } else if packed {
        "its latents code smaller than that even unsteered (--memory-factor 2 gives them the \
         most room)"
    } else {
        "the layout's largest grids do not reach that rate on this material"
    };
    (off.abs() > 0.05).then(|| {
        format!(
            "note: {:.3} BPPC ({}) is {:+.0} % from {}'s nominal {nominal}: {why}",
            e.quality.bppc,
            if packed { "on disk" } else { "fixed-rate" },
            100.0 * off,
            e.config.profile
        )
    })
}

/// Encodes with profiles from the smallest rate up until the whole-chain PSNR reaches `target`;
/// `base` gives every other option, and with `hi_bilinear` the NTC profiles read their
/// high-resolution grids that way (`--hi-bilinear`).
fn search_target(
    set: &TextureSet,
    target: f64,
    base: &EncodeOptions,
    hi_bilinear: Option<bool>,
) -> Result<Encoded> {
    if !target.is_finite() || target <= 0.0 {
        return Err(Box::new(EncodeError::BadOption {
            option: EncodeOption::TargetPsnr,
            value: target.to_string(),
            reason: "must be a positive number of dB",
        }));
    }
    let mut order: Vec<Profile> = PROFILES.to_vec();
    order.sort_by(|a, b| a.bppc().total_cmp(&b.bppc()));
    let mut last = None;
    for profile in order {
        let profile = hi_bilinear.and_then(|on| profile.with_hi_bilinear(on)).unwrap_or(profile);
        let e = encode_with_progress(set, &EncodeOptions { profile, ..base.clone() })?;
        eprintln!("  {:9} {:.3} BPPC  {:.2} dB", profile.name(), e.quality.bppc, e.quality.psnr);
        if e.quality.psnr >= target {
            return Ok(e);
        }
        last = Some(e);
    }
    eprintln!("no profile reached {target} dB; keeping the largest");
    last.ok_or_else(|| "no profile".into())
}
