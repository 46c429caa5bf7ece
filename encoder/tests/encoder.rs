//! Encoder behaviour: determinism, quality on the procedural material, agreement of the two
//! decoders on trained files, role detection, and clear errors for bad input.
// Test code: an unwrap that fails fails the test (clippy.toml allows it only inside #[test]).
#![allow(clippy::unwrap_used)]

use nmat_core::{ChannelMask, Container};
use nmat_encode::texset::{self, FileLayout, LoadOptions, Role, role_from_name};
use nmat_encode::{
    DEFAULT_MEMORY_FACTOR, EncodeError, EncodeOption, EncodeOptions, LayoutChoice, ModelConfig,
    Profile, Storage, TrainKernel, TrainOptions, demo, encode, layouts, source_maps,
};
use std::path::{Path, PathBuf};

fn options(profile: &str, steps: usize, seed: u64) -> EncodeOptions {
    EncodeOptions {
        profile: Profile::by_name(profile).unwrap(),
        train: TrainOptions { steps, seed, ..TrainOptions::default() },
        ..EncodeOptions::default()
    }
}

#[test]
fn same_inputs_seed_and_steps_give_identical_files_for_any_thread_count_and_kernel() {
    let set = demo::bricks(64);
    let run = |threads: usize, kernel: TrainKernel| {
        let mut opts = options("ntc-0.5", 60, 7);
        opts.train.kernel = Some(kernel);
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| encode(&set, &opts, &mut |_| {}).unwrap().bytes)
    };
    // The portable twin is the reference; every kernel this CPU has must give its bytes.
    let one = run(1, TrainKernel::Scalar);
    assert_eq!(one, run(2, TrainKernel::Scalar), "other thread count");
    let kernels: Vec<_> = TrainKernel::ALL.into_iter().filter(|k| k.is_available()).collect();
    eprintln!("kernels on this CPU: {:?}", kernels);
    for kernel in kernels {
        assert_eq!(one, run(1, kernel), "{} on 1 thread", kernel.name());
        assert_eq!(one, run(2, kernel), "{} on 2 threads", kernel.name());
    }
    let other_seed = encode(&set, &options("ntc-0.5", 60, 8), &mut |_| {}).unwrap().bytes;
    assert_ne!(one, other_seed, "the seed matters");
}

/// A margin left open (`None`) is the profile's; one given wins, and it changes the file where
/// outputs pass an end of their range (the procedural material's normal z sits at 1 on flat
/// ground).
#[test]
fn the_output_margin_left_open_is_the_profile_s() {
    let set = demo::bricks(64);
    let run = |profile: &str, margin: Option<f32>| {
        let mut o = options(profile, 60, 2);
        o.train.output_margin = margin;
        encode(&set, &o, &mut |_| {}).unwrap().bytes
    };
    for profile in ["ntc-0.2", "ntc-1.0", "nbc-0.1"] {
        let own = Profile::by_name(profile).unwrap().output_margin();
        assert_eq!(run(profile, None), run(profile, Some(own)), "{profile}");
    }
    for profile in ["ntc-0.2", "nbc-0.1"] {
        assert!(Profile::by_name(profile).unwrap().output_margin() > 0.0, "{profile}");
    }
    assert_ne!(run("ntc-0.2", None), run("ntc-0.2", Some(0.0)), "the margin changes nothing");
}

#[test]
fn an_output_margin_out_of_its_range_is_refused_before_training() {
    let set = demo::bricks(16);
    for margin in [-0.01, 0.26, f32::NAN, f32::INFINITY] {
        let mut o = options("ntc-0.2", 50, 1);
        o.train.output_margin = Some(margin);
        let mut steps = 0;
        match encode(&set, &o, &mut |_| steps += 1) {
            Err(EncodeError::BadOption { option: EncodeOption::OutputMargin, value, .. }) => {
                assert_eq!(value, margin.to_string());
            }
            other => panic!("margin {margin}: {:?}", other.map(|e| e.bytes.len())),
        }
        assert_eq!(steps, 0, "margin {margin}: trained before refusing");
    }
    for margin in [0.0, nmat_encode::MAX_OUTPUT_MARGIN] {
        assert!(nmat_encode::check_output_margin(margin).is_ok(), "{margin}");
    }
}

#[test]
fn training_reaches_a_useful_quality_on_the_procedural_material() {
    let set = demo::bricks(64);
    for (profile, floor_db) in [("ntc-1.0", 27.0), ("nbc-0.5", 24.0)] {
        let before = encode(&set, &options(profile, 1, 3), &mut |_| {}).unwrap().quality.psnr;
        let after = encode(&set, &options(profile, 600, 3), &mut |_| {}).unwrap().quality.psnr;
        eprintln!("{profile}: {before:.2} dB after 1 step, {after:.2} dB after 600");
        assert!(after > floor_db, "{profile}: {after} dB");
        assert!(after > before + 5.0, "{profile}: training did not help ({before} → {after})");
    }
}

/// The stored network's output biases are calibrated on the chain: a network after one step is
/// far off its targets' means, and the file comes out with the mean error over the chain of
/// every learned channel that no decoded texel clamps (whose outputs all move with its bias)
/// within a fraction of a code of 0.
#[test]
fn output_biases_are_calibrated_to_the_chain_s_mean() {
    let set = demo::bricks(64);
    for profile in ["ntc-0.2", "nbc-0.1"] {
        // Without the latent polish, which moves the latents after the refit: the calibration
        // is what is measured here.
        let o = EncodeOptions { polish_sweeps: Some(0), ..options(profile, 1, 3) };
        let out = encode(&set, &o, &mut |_| {}).unwrap();
        let m = Container::parse(&out.bytes).unwrap();
        let c = set.channel_count();
        let mut clamped = vec![false; c];
        let (mut sum, mut count) = (vec![0f64; c], 0f64);
        for (mip, src) in set.mips.iter().enumerate() {
            let decoded = nmat_encode::metrics::decode_mip(&m, mip as u32);
            for (i, (&d, &s)) in decoded.iter().zip(&src.data).enumerate() {
                clamped[i % c] |= d == 0.0 || d == 1.0;
                sum[i % c] += f64::from(d - s);
            }
            count += f64::from(src.width * src.height);
        }
        let mut checked = 0;
        for ch in set.learned_channels().into_iter().filter(|&ch| !clamped[ch]) {
            let mean = sum[ch] / count;
            eprintln!("{profile}: channel {ch} mean error {:+.2} codes", mean * 255.0);
            assert!(
                mean.abs() * 255.0 < 0.25,
                "{profile}: channel {ch}: {:+.3} codes",
                mean * 255.0
            );
            checked += 1;
        }
        assert!(checked >= 2, "{profile}: only {checked} channels without a clamped texel");
    }
}

#[test]
fn integer_and_float_decoders_agree_on_a_trained_material() {
    let set = demo::bricks(64);
    let out = encode(&set, &options("ntc-0.5", 300, 5), &mut |_| {}).unwrap();
    let m = Container::parse(&out.bytes).unwrap();
    let a = nmat_tests::int_vs_float(&m);
    eprintln!(
        "trained material: max |Δ| {}, mean Δ {:+.4} over {} codes",
        a.max_abs, a.mean, a.count
    );
    assert!(a.max_abs <= 1);
    assert!(a.mean.abs() < 0.05);
}

#[test]
fn the_lod_feature_is_format_2_3_s_unless_older_readers_are_asked_for() {
    // By default the LOD feature is mip / 2 (code 4), flagged so that readers before 2.3 refuse
    // the file; `legacy_lod` trains on mip / 16 (code 1) and writes what 2.0 (fixed-rate) and
    // 2.2 (packed) readers take: no header flag, their minor versions.
    let set = demo::bricks(32);
    for (legacy, code, flags, minors) in [(false, 4, 1, (3, 3)), (true, 1, 0, (0, 2))] {
        let out = encode(
            &set,
            &EncodeOptions { legacy_lod: legacy, ..options("ntc-0.5", 40, 2) },
            &mut |_| {},
        )
        .unwrap();
        let fixed = Container::parse(&out.bytes).unwrap();
        let nmat_core::Body::Neural(n) = fixed.body() else { panic!("a neural material") };
        assert_eq!(n.mlp().lod_code(), code, "legacy {legacy}");
        let packed = out.packed.as_deref().unwrap();
        for (bytes, minor) in [(&out.bytes[..], minors.0), (packed, minors.1)] {
            let header = |at: usize| u16::from_le_bytes([bytes[at], bytes[at + 1]]);
            assert_eq!((header(6), header(8)), (minor, flags), "legacy {legacy}");
        }
        let a = nmat_tests::int_vs_float(&fixed);
        assert!(a.max_abs <= 1, "legacy {legacy}: {}", a.max_abs);
    }
}

/// The solver's byte budget is the writer's file size, for every profile (the rate promise of
/// docs/ENCODING.md rests on it).
#[test]
fn predicted_file_sizes_are_the_written_ones() {
    for size in [64, 96] {
        let set = demo::bricks(size);
        let shape = nmat_encode::shape_of(&set);
        for p in nmat_encode::PROFILES {
            let out = encode(&set, &options(p.name(), 1, 1), &mut |_| {}).unwrap();
            let predicted = out.config.byte_budget(&shape);
            assert_eq!(
                predicted.total(),
                out.bytes.len(),
                "{} at {size}²: {predicted:?}",
                p.name()
            );
        }
    }
}

/// Rate control (docs/ENCODING.md): a packed file lands within ±5 % of its profile's nominal
/// rate on disk, with a larger layout in memory; the nominal layout alone (memory factor 1)
/// lands further below. The trainer's measure of the coded latents is what packing writes.
#[test]
fn packed_files_land_at_the_nominal_rate_on_disk() {
    let set = demo::bricks(256);
    for profile in ["ntc-0.5", "nbc-0.5"] {
        let nominal = Profile::by_name(profile).unwrap().bppc();
        let steered = encode(&set, &options(profile, 800, 2), &mut |_| {}).unwrap();
        if profile == "ntc-0.5" {
            // Steering is as deterministic as training: one thread gives the same bytes (the
            // pull is elementwise IEEE arithmetic, the same in every kernel's lanes).
            let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
            let one = options(profile, 800, 2);
            let bytes = pool.install(|| encode(&set, &one, &mut |_| {}).unwrap().bytes);
            assert!(bytes == steered.bytes, "steered training depends on the thread count");
        }
        let q = &steered.quality;
        eprintln!("{profile}: {:.4} BPPC on disk, {:.4} in memory", q.bppc, q.memory_bppc);
        assert!((q.bppc / nominal - 1.0).abs() <= 0.05, "{profile}: {} on disk", q.bppc);
        assert!(q.memory_bppc > 1.3 * nominal, "{profile}: {} in memory", q.memory_bppc);
        let plain = EncodeOptions { memory_factor: 1.0, ..options(profile, 800, 2) };
        let plain = encode(&set, &plain, &mut |_| {}).unwrap().quality;
        assert!(plain.bppc < q.bppc, "{profile}: {} unsteered", plain.bppc);
        assert!((plain.memory_bppc / nominal - 1.0).abs() <= 0.02, "{profile}: nominal layout");

        // The coded size the trainer steers by is the packed section's, less its 8-byte header.
        let m = Container::parse(&steered.bytes).unwrap();
        let grids: Vec<(u32, u32, u32, u32, Vec<u8>)> = m
            .neural()
            .unwrap()
            .grids()
            .iter()
            .map(|g| {
                let codes = (0..g.height())
                    .flat_map(|y| (0..g.width()).map(move |x| (x, y)))
                    .flat_map(|(x, y)| (0..g.channels()).map(move |c| g.code(x, y, c)))
                    .collect();
                (g.width(), g.height(), g.channels() as u32, g.bits_per_latent(), codes)
            })
            .collect();
        let views: Vec<(u32, u32, u32, u32, &[u8])> =
            grids.iter().map(|(w, h, c, b, codes)| (*w, *h, *c, *b, codes.as_slice())).collect();
        let packed = steered.packed.as_deref().unwrap();
        let (_, length) = nmat_tests::files::section(packed, 6); // PACKED_LATENTS
        assert_eq!(nmat_core::internals::coded_latents_len(&views) + 8, length, "{profile}");
    }
}

/// `ntc-0.2` reads every level's high-resolution grid twice, at its 4 nearest cells and
/// bilinearly (docs/ENCODING.md, "The high-resolution grid read twice"), in every layout it can
/// take (both ways of the trial, fixed-rate, nominal); the other NTC profiles keep NTC's two terms.
#[test]
fn ntc_0_2_reads_its_high_resolution_grids_twice_in_every_layout() {
    use nmat_core::TermMode::{Bilinear, Nearest4};
    let shape = nmat_encode::shape_of(&demo::bricks(384));
    for name in ["ntc-0.2", "ntc-0.5", "ntc-1.0", "ntc-2.25"] {
        let profile = Profile::by_name(name).unwrap();
        let twice = name == "ntc-0.2";
        let mut configs = Vec::new();
        for (storage, factor) in [
            (Storage::Packed, DEFAULT_MEMORY_FACTOR),
            (Storage::Packed, 1.0),
            (Storage::FixedRate, 1.5),
        ] {
            configs.extend(
                layouts(profile, &shape, storage, factor).unwrap().into_iter().map(|w| w.config),
            );
        }
        assert!(configs.len() >= 3, "{name}");
        for config in &configs {
            for terms in &config.levels {
                let modes: Vec<_> = terms.iter().map(|t| (t.mode, t.grids.clone())).collect();
                let hi = terms[0].grids[0];
                let mut expected = vec![(Nearest4, vec![hi]), (Bilinear, vec![hi + 1])];
                if twice {
                    expected.push((Bilinear, vec![hi]));
                }
                assert_eq!(modes, expected, "{name}");
            }
            // The third term's features are inputs of the network.
            let hi_channels = config.grids[0].channels;
            let lo_channels = config.grids[1].channels;
            let extra = if twice { hi_channels } else { 0 };
            let position = 4 * usize::from(config.pe_frequencies) + 1; // PE and the LOD
            assert_eq!(
                config.input_width(),
                4 * hi_channels + lo_channels + extra + position,
                "{name}"
            );
        }
    }
}

/// `Profile::with_hi_bilinear` turns the third term on or off at any NTC profile (the same
/// grids; the network's input grows by the high-resolution channels); NBC profiles have none.
#[test]
fn any_ntc_profile_reads_its_high_resolution_grids_twice_on_request() {
    let shape = nmat_encode::shape_of(&demo::bricks(256));
    for name in ["ntc-0.2", "ntc-0.5", "ntc-1.0", "ntc-2.25"] {
        let profile = Profile::by_name(name).unwrap();
        assert_eq!(profile.hi_bilinear(), Some(name == "ntc-0.2"), "{name}");
        let [once, twice] = [false, true].map(|on| {
            let p = profile.with_hi_bilinear(on).unwrap();
            assert_eq!((p.name(), p.bppc(), p.hi_bilinear()), (name, profile.bppc(), Some(on)));
            layouts(p, &shape, Storage::FixedRate, 1.0).unwrap().remove(0).config
        });
        assert!(once.levels.iter().all(|terms| terms.len() == 2), "{name}");
        assert!(twice.levels.iter().all(|terms| terms.len() == 3), "{name}");
        for (a, b) in once.levels.iter().zip(&twice.levels) {
            assert_eq!(b[2].grids, b[0].grids, "{name}: the third term reads the first's grid");
            assert_eq!(&b[..2], &a[..], "{name}: the first two terms as without it");
        }
    }
    for name in ["nbc-0.05", "nbc-0.1", "nbc-0.2", "nbc-0.5"] {
        let p = Profile::by_name(name).unwrap();
        assert_eq!((p.hi_bilinear(), p.with_hi_bilinear(true)), (None, None), "{name}");
    }
}

/// The layout trial (docs/ENCODING.md): a packed `ntc-0.2` file can grow its in-memory layout
/// by the grids' resolution first or by one more bit per latent first; the trial trains each way
/// for a quarter of the steps and keeps the one whose file decodes better, then trains it in full.
#[test]
fn the_layout_trial_keeps_the_way_whose_short_training_decoded_better() {
    // A size whose two ways differ: on some (512² since `ntc-0.2` reads its high-resolution
    // grids twice, whose solved layout has 8 channels there; 160² and below) the grids at their
    // largest stay far under the memory factor, so the grids' resolution way takes the bit too
    // and the two are one. 192² is the smallest of the demo's sizes with two ways: every encode
    // here polishes its latents, and a polish costs about its size in decodes of the chain.
    let set = demo::bricks(192);
    let shape = nmat_encode::shape_of(&set);
    let profile = Profile::by_name("ntc-0.2").unwrap();
    let ways = layouts(profile, &shape, Storage::Packed, DEFAULT_MEMORY_FACTOR).unwrap();
    assert_eq!(ways.len(), 2, "{ways:?}");
    let bits = |c: &ModelConfig| c.grids.iter().map(|g| g.bits).collect::<Vec<_>>();
    let more: Vec<u8> = bits(&ways[0].config).iter().map(|b| b + 1).collect();
    assert_eq!(bits(&ways[1].config), more, "one more bit on every grid");
    let size = |c: &ModelConfig| c.byte_budget(&shape).total() as f64;
    let target = DEFAULT_MEMORY_FACTOR * shape.budget_bits(0.2) / 8.0;
    assert!(ways.iter().all(|w| size(&w.config) <= target * 1.02), "within the memory factor");
    // One way only for the other profiles, for fixed-rate files and for the nominal layout.
    for other in ["ntc-0.5", "ntc-1.0", "nbc-0.1"] {
        let p = Profile::by_name(other).unwrap();
        assert_eq!(layouts(p, &shape, Storage::Packed, 1.5).unwrap().len(), 1, "{other}");
    }
    assert_eq!(layouts(profile, &shape, Storage::FixedRate, 1.5).unwrap().len(), 1);
    assert_eq!(layouts(profile, &shape, Storage::Packed, 1.0).unwrap().len(), 1);

    let (steps, quarter) = (80, 20);
    // Each way asked for alone, as a trial trains it: a quarter of the steps, no polish (a trial
    // does not polish its latents: the final encode does). Unpolished, no file is trained again
    // on a larger layout, so each keeps its way's layout.
    let unpolished = |layout: LayoutChoice| {
        let o = EncodeOptions { layout, polish_sweeps: Some(0), ..options("ntc-0.2", quarter, 3) };
        encode(&set, &o, &mut |_| {}).unwrap()
    };
    let resolution_first = unpolished(LayoutChoice::ResolutionFirst);
    let bits_first = unpolished(LayoutChoice::BitsFirst);
    assert_eq!((&resolution_first.config, resolution_first.trial), (&ways[0].config, None));
    assert_eq!((&bits_first.config, bits_first.trial), (&ways[1].config, None));
    // The default is one more bit per latent first, without a trial (the CLI test encodes with
    // the default and with `--layout bits-first` and compares the files).
    assert_eq!(EncodeOptions::default().layout, LayoutChoice::BitsFirst);
    let mut counted = Vec::new();
    let o = EncodeOptions { layout: LayoutChoice::Trial, ..options("ntc-0.2", steps, 3) };
    let tried = encode(&set, &o, &mut |p| counted.push((p.step, p.steps))).unwrap();
    let trial = tried.trial.unwrap();
    // Each way's trial is that way trained for a quarter of the steps.
    assert_eq!(trial.resolution_first_db, resolution_first.quality.psnr);
    assert_eq!(trial.bits_first_db, bits_first.quality.psnr);
    let kept = if trial.bits_first_db > trial.resolution_first_db {
        LayoutChoice::BitsFirst
    } else {
        LayoutChoice::ResolutionFirst
    };
    // The file is the kept way trained in full (polished, and trained again on a larger layout
    // where it lands under its size, as any encode).
    let o = EncodeOptions { layout: kept, ..options("ntc-0.2", steps, 3) };
    let kept = encode(&set, &o, &mut |_| {}).unwrap();
    eprintln!("trial: {trial:?}; kept {:?}", bits(&kept.config));
    assert!(tried.bytes == kept.bytes, "the file is the kept way trained in full");
    // Progress counts the trials' steps with the training's, and ends at their sum; a file more
    // than 0.3 % under its nominal size is trained once more on a larger layout (kept only where
    // it decodes better: docs/ENCODING.md, "The regrown layout"), whose steps count too.
    assert!(counted.windows(2).all(|w| w[0].0 <= w[1].0), "{counted:?}");
    let &(last, total) = counted.last().unwrap();
    assert_eq!(last, total, "progress ends at its total");
    let trained = steps + 2 * quarter;
    assert!(total == trained || total == trained + steps, "{total} steps counted");
    // A file still under its size was trained again (and the larger layout not kept).
    let nominal = shape.budget_bits(0.2) / 8.0;
    if (tried.file().len() as f64) < nominal * (1.0 - 0.003) {
        assert_eq!(total, trained + steps, "a file under its size, not trained again");
    }
}

#[test]
fn roles_are_detected_from_common_names() {
    let cases = [
        ("brick_albedo.png", Some(Role::Albedo)),
        ("Brick_Diffuse.TGA", Some(Role::Albedo)),
        ("wall-basecolor.jpg", Some(Role::Albedo)),
        ("wall_base_color.png", Some(Role::Albedo)),
        ("rock_n.png", Some(Role::Normal)),
        ("rock_nm.tga", Some(Role::Normal)),
        ("rock_norm.png", Some(Role::Normal)),
        ("metal_roughness.png", Some(Role::Roughness)),
        ("metal_gloss.png", Some(Role::Gloss)),
        ("metal_spec.png", Some(Role::Specular)),
        ("metal_s.png", Some(Role::Specular)),
        ("sand_height.png", Some(Role::Height)),
        ("sand_z.png", Some(Role::Height)),
        ("sand_bump.png", Some(Role::Height)),
        ("sand_disp.exr.png", Some(Role::Height)),
        ("tile_ao.png", Some(Role::Ao)),
        ("tile_metallic.png", Some(Role::Metallic)),
        ("lamp_glow.png", Some(Role::Emissive)),
        ("lamp_emissive.png", Some(Role::Emissive)),
        ("leaf_opacity.png", Some(Role::Opacity)),
        ("rock_normal_ao.png", Some(Role::Ao)),
        ("eX_floor_grate_03.tga", None),
    ];
    for (name, role) in cases {
        assert_eq!(role_from_name(Path::new(name)), role, "{name}");
    }
}

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("nmat-encoder-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn gradient_rgb(w: u32, h: u32) -> image::RgbImage {
    image::RgbImage::from_fn(w, h, |x, y| {
        image::Rgb([(x * 255 / w.max(1)) as u8, (y * 255 / h.max(1)) as u8, 128])
    })
}

#[test]
fn bad_inputs_give_errors_that_name_the_file() {
    let dir = temp_dir("bad");
    // Empty folder.
    let empty = dir.join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    assert!(matches!(texset::collect_inputs(&[empty]), Err(EncodeError::NoMaps { .. })));
    // A name without a role.
    let unnamed = dir.join("mystery.png");
    gradient_rgb(8, 8).save(&unnamed).unwrap();
    let e = texset::assign_roles(std::slice::from_ref(&unnamed), &[]).unwrap_err();
    assert!(e.to_string().contains("mystery.png"), "{e}");
    // Two maps of one role.
    let a = dir.join("a_albedo.png");
    let b = dir.join("b_diffuse.png");
    gradient_rgb(8, 8).save(&a).unwrap();
    gradient_rgb(8, 8).save(&b).unwrap();
    assert!(matches!(
        texset::assign_roles(&[a.clone(), b], &[]),
        Err(EncodeError::DuplicateRole { .. })
    ));
    // Sizes that differ, then --resize.
    let n = dir.join("a_normal.png");
    gradient_rgb(16, 8).save(&n).unwrap();
    let roles = texset::assign_roles(&[a.clone(), n.clone()], &[]).unwrap();
    let e = texset::load(&roles, &LoadOptions::default()).unwrap_err();
    assert!(
        matches!(e, EncodeError::SizeMismatch { ref path, size: (16, 8), expected: (8, 8), .. } if path == &n),
        "{e}"
    );
    let set =
        texset::load(&roles, &LoadOptions { resize: true, ..LoadOptions::default() }).unwrap();
    assert_eq!((set.width, set.height, set.channel_count()), (8, 8, 6));
    // Not an image at all.
    let junk = dir.join("junk_albedo.png");
    std::fs::write(&junk, b"this is not a PNG").unwrap();
    let e = texset::load(&[(Role::Albedo, junk.clone())], &LoadOptions::default()).unwrap_err();
    assert!(matches!(e, EncodeError::Image { ref path, .. } if path == &junk), "{e}");
    // A missing file.
    let e = texset::load(&[(Role::Albedo, dir.join("missing.png"))], &LoadOptions::default())
        .unwrap_err();
    assert!(matches!(e, EncodeError::Io { .. }), "{e}");
    // More than 16 channels: five RGBA maps with varying alpha.
    let roles: Vec<(Role, PathBuf)> =
        [Role::Albedo, Role::Normal, Role::Specular, Role::Emissive, Role::Roughness]
            .iter()
            .map(|&r| {
                let p = dir.join(format!("x_{}.png", r.name()));
                image::RgbaImage::from_fn(4, 4, |x, y| {
                    image::Rgba([x as u8 * 9, y as u8 * 7, (x + y) as u8, (x * y) as u8 * 5])
                })
                .save(&p)
                .unwrap();
                (r, p)
            })
            .collect();
    let e = texset::load(&roles, &LoadOptions::default()).unwrap_err();
    assert!(matches!(e, EncodeError::TooManyChannels { channels: 20, limit: 16 }), "{e}");
    // --map syntax.
    assert!(matches!(
        texset::parse_map_argument("albedo"),
        Err(EncodeError::BadMapArgument { .. })
    ));
    assert!(matches!(
        texset::parse_map_argument("colour=x.png"),
        Err(EncodeError::BadMapArgument { .. })
    ));
    assert_eq!(texset::parse_map_argument("AO=x.png").unwrap(), (Role::Ao, PathBuf::from("x.png")));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn maps_without_a_signature_are_read_by_their_extension() {
    // TGA has no magic number: its extension names the format (as for any map `load` reads).
    let dir = temp_dir("tga");
    let png = dir.join("a_albedo.png");
    let tga = dir.join("b_albedo.tga");
    gradient_rgb(16, 8).save(&png).unwrap();
    gradient_rgb(16, 8).save(&tga).unwrap();
    let load = |p: &std::path::Path| {
        texset::load(&[(Role::Albedo, p.to_path_buf())], &LoadOptions::default()).unwrap()
    };
    let (from_png, from_tga) = (load(&png), load(&tga));
    assert_eq!(from_tga.mips[0].data, from_png.mips[0].data);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn pixel_formats_are_packed_as_documented() {
    let dir = temp_dir("formats");
    // 16-bit gray, gray stored as RGB, constant alpha, constant map (palette and CMYK: below).
    let h16 = dir.join("s_height.png");
    image::ImageBuffer::<image::Luma<u16>, _>::from_fn(8, 8, |x, y| {
        image::Luma([(x * 8000 + y * 100) as u16])
    })
    .save(&h16)
    .unwrap();
    let gloss = dir.join("s_gloss.png");
    image::RgbImage::from_fn(8, 8, |x, _| image::Rgb([x as u8 * 30; 3])).save(&gloss).unwrap();
    let albedo = dir.join("s_albedo.png");
    image::RgbaImage::from_fn(8, 8, |x, y| image::Rgba([x as u8 * 20, y as u8 * 20, 3, 255]))
        .save(&albedo)
        .unwrap();
    let ao = dir.join("s_ao.png");
    image::GrayImage::from_pixel(8, 8, image::Luma([200])).save(&ao).unwrap();
    let roles =
        texset::assign_roles(&texset::collect_inputs(std::slice::from_ref(&dir)).unwrap(), &[])
            .unwrap();
    let set = texset::load(&roles, &LoadOptions::default()).unwrap();
    let names: Vec<&str> = set.channels.iter().map(|c| c.name.as_str()).collect();
    assert_eq!(names, ["albedo.r", "albedo.g", "albedo.b", "gloss", "height", "ao"]);
    let by_role = |r: Role| set.maps.iter().find(|m| m.role == r).unwrap();
    assert_eq!(by_role(Role::Albedo).alpha_value, Some(255), "constant alpha is noted, not stored");
    assert_eq!(by_role(Role::Albedo).layout, FileLayout::Rgba);
    assert!(by_role(Role::Gloss).gray_rgb, "R = G = B is one channel");
    assert!(by_role(Role::Height).sixteen_bit);
    assert_eq!(
        set.channels[5].constant,
        Some(200.0 / 255.0),
        "a constant map is a constant channel"
    );
    assert_eq!(set.channels[2].constant, Some(3.0 / 255.0));
    assert_eq!(set.mips.len(), 4);
    assert_eq!(set.learned_channels(), vec![0, 1, 3, 4]);
    // The encoded file keeps the constants exactly and the layout in SOURCE_MAPS.
    let out = encode(&set, &options("ntc-0.5", 20, 1), &mut |_| {}).unwrap();
    let m = Container::parse(&out.bytes).unwrap();
    assert_eq!(
        (m.channels()[5].range_min, m.channels()[5].range_max),
        (200.0 / 255.0, 200.0 / 255.0)
    );
    let mut v = [0f32; 1];
    m.decode_texel(3, 3, 1, ChannelMask::single(5), &mut v).unwrap();
    assert_eq!(v[0], 200.0 / 255.0);
    let maps = source_maps::decode(
        m.optional_section(nmat_core::SectionKind(source_maps::SECTION_KIND)).unwrap(),
    )
    .unwrap();
    assert_eq!(maps, set.maps);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A constant 16-bit alpha that no 8-bit code equals is not folded into SOURCE_MAPS' one-byte
/// alpha (it would come back changed): it stays a constant channel. One that a byte holds exactly
/// (a multiple of 257) is folded as usual.
#[test]
fn a_constant_sixteen_bit_alpha_is_kept_exactly() {
    let dir = temp_dir("alpha16");
    let load = |alpha: u16| {
        let p = dir.join(format!("a{alpha}_albedo.png"));
        image::ImageBuffer::<image::Rgba<u16>, _>::from_fn(8, 8, |x, y| {
            image::Rgba([(x * 3000) as u16, (y * 3000) as u16, 7, alpha])
        })
        .save(&p)
        .unwrap();
        texset::load(&[(Role::Albedo, p)], &LoadOptions::default()).unwrap()
    };
    let set = load(40_000);
    assert_eq!(set.maps[0].alpha_value, None);
    assert_eq!(set.channels.len(), 4);
    assert_eq!(set.channels[3].constant, Some(40_000.0 / 65535.0));
    let set = load(200 * 257);
    assert_eq!(set.maps[0].alpha_value, Some(200));
    assert_eq!(set.channels.len(), 3);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn source_maps_never_name_a_path() {
    let mut maps = demo::bricks(32).maps;
    // A name out of the folder comes back a bare file name (nmat_encode::names::file_name).
    maps[0].file_name = "../evil.png".into();
    let read = source_maps::decode(&source_maps::encode(&maps)).unwrap();
    assert_eq!(read[0].file_name, "_._evil.png");
    maps[0].file_name = "ok.png".into();
    assert_eq!(source_maps::decode(&source_maps::encode(&maps)).unwrap(), maps);
    assert_eq!(source_maps::decode(&[1, 0, 5, 0]), None, "count beyond the bytes");
}

/// A palette PNG is expanded to its colours (a documented conversion), and a
/// CMYK JPEG either arrives converted to RGB or is refused with an error naming the file — never
/// a panic.
#[test]
fn palette_and_cmyk_inputs_are_converted_or_refused_clearly() {
    let dir = temp_dir("palette_cmyk");
    // An 8×8 indexed PNG: 4 palette entries, index = (x + y) % 4.
    let palette: [[u8; 3]; 4] = [[255, 0, 0], [0, 255, 0], [0, 0, 255], [128, 128, 128]];
    let albedo = dir.join("p_albedo.png");
    {
        let file = std::io::BufWriter::new(std::fs::File::create(&albedo).unwrap());
        let mut enc = png::Encoder::new(file, 8, 8);
        enc.set_color(png::ColorType::Indexed);
        enc.set_depth(png::BitDepth::Eight);
        enc.set_palette(palette.concat());
        let mut writer = enc.write_header().unwrap();
        let indices: Vec<u8> = (0..64).map(|i| ((i % 8 + i / 8) % 4) as u8).collect();
        writer.write_image_data(&indices).unwrap();
    }
    let roles = vec![(Role::Albedo, albedo.clone())];
    let set = texset::load(&roles, &LoadOptions::default()).unwrap();
    let names: Vec<&str> = set.channels.iter().map(|c| c.name.as_str()).collect();
    assert_eq!(names, ["albedo.r", "albedo.g", "albedo.b"], "palette expanded to RGB");
    let top = &set.mips[0];
    for (i, texel) in top.data.chunks_exact(3).enumerate() {
        let want = palette[(i % 8 + i / 8) % 4].map(|v| f32::from(v) / 255.0);
        assert_eq!(texel, want, "texel {i}");
    }

    // A CMYK JPEG (Adobe-style, as print workflows write them).
    let cmyk = dir.join("c_albedo.jpg");
    let pixels: Vec<u8> = (0..16 * 16).flat_map(|i| [(i % 256) as u8, 40, 200, 10]).collect();
    jpeg_encoder::Encoder::new_file(&cmyk, 90)
        .unwrap()
        .encode(&pixels, 16, 16, jpeg_encoder::ColorType::Cmyk)
        .unwrap();
    match texset::load(&[(Role::Albedo, cmyk.clone())], &LoadOptions::default()) {
        Ok(set) => {
            assert_eq!(set.channels.len(), 3, "CMYK arrives as RGB");
            assert!(set.mips[0].data.iter().all(|v| (0.0..=1.0).contains(v)));
        }
        Err(e) => assert!(e.to_string().contains("c_albedo.jpg"), "{e}"),
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn the_chain_decode_reports_every_texel_once_and_decodes_what_the_definition_does() {
    // 70 rows: two full bands of 32 rows and a partial one at mip 0.
    let set = demo::bricks(70);
    let out = encode(&set, &options("ntc-0.5", 5, 1), &mut |_| {}).unwrap();
    let m = Container::parse(&out.bytes).unwrap();
    let mut reports = Vec::new();
    let decoded = nmat_encode::metrics::decode_mip_with(&m, 0, &mut |t| reports.push(t));
    assert_eq!(reports, [32 * 70, 32 * 70, 6 * 70]);
    let c = m.channel_count();
    let mut codes = vec![0u8; c];
    for (x, y) in [(0, 0), (69, 31), (3, 32), (69, 69)] {
        m.decode_texel_u8(x, y, 0, ChannelMask::ALL, &mut codes).unwrap();
        let at = (y as usize * 70 + x as usize) * c;
        let got: Vec<u8> = decoded[at..at + c].iter().map(|v| (v * 255.0).round() as u8).collect();
        assert_eq!(got, codes, "texel ({x}, {y})");
    }
    let mut total = 0;
    let q = nmat_encode::metrics::chain_quality_with(&m, &set, &mut |t| total += t);
    let texels: u64 = (0..m.mip_count()).map(|mip| m.decode_cost(mip).texels).sum();
    assert_eq!(total, texels);
    assert_eq!(q.psnr, nmat_encode::metrics::chain_quality(&m, &set).psnr);
}

/// The quality figures every table of the project reports (PSNR over all channels of the whole
/// chain, MSE per mip and channel, PSNR of channel subsets, SSIM at mip 0, mean error, BPPC),
/// against a source made of the decode itself plus errors placed by hand, so that each figure
/// follows by arithmetic, not from the code measured.
#[test]
fn quality_figures_follow_from_known_errors() {
    use nmat_encode::metrics::{chain_quality, decode_mip, psnr, ssim_channel};
    use nmat_encode::texset::{ChannelInfo, MipImage, TextureSet};
    use nmat_tests::generate::{FixtureConfig, generate};
    // albedo r, g, b and a normal's x held constant at 0.5 (unit (0.5 + 1) / 2 in −1 … 1);
    // mips 24 × 16, 12 × 8, 6 × 4, 3 × 2, 1 × 1: 511 texels.
    let mut spec = generate(&FixtureConfig::ntc("quality", 4, 24, 16, 4));
    (spec.channels[3].range_min, spec.channels[3].range_max) = (0.5, 0.5);
    let bytes = spec.to_bytes().unwrap();
    let m = Container::parse(&bytes).unwrap();
    let mut mips: Vec<MipImage> = (0..m.mip_count())
        .map(|mip| {
            let (width, height) = m.mip_size(mip);
            let mut data = decode_mip(&m, mip);
            data.chunks_mut(4).for_each(|px| px[3] = 0.75);
            MipImage { width, height, data }
        })
        .collect();
    let decoded0 = mips[0].data.clone();
    // Mip 0, channel 0: every texel 0.125 below the decode. Mip 1, channel 1: the even columns
    // (48 of 96 texels) 0.25 above. Mip 2, the constant channel: 0.5 above its value.
    mips[0].data.chunks_mut(4).for_each(|px| px[0] -= 0.125);
    for (i, px) in mips[1].data.chunks_mut(4).enumerate() {
        if i % 12 % 2 == 0 {
            px[1] += 0.25;
        }
    }
    mips[2].data.chunks_mut(4).for_each(|px| px[3] += 0.5);
    let channel = |name: &str, role, component| ChannelInfo {
        name: name.into(),
        role,
        component,
        constant: None,
    };
    let set = TextureSet {
        width: 24,
        height: 16,
        channels: vec![
            channel("albedo.r", Role::Albedo, 0),
            channel("albedo.g", Role::Albedo, 1),
            channel("albedo.b", Role::Albedo, 2),
            ChannelInfo { constant: Some(0.75), ..channel("normal.x", Role::Normal, 0) },
        ],
        maps: vec![],
        mips,
    };
    let q = chain_quality(&m, &set);
    let near = |a: f64, b: f64, what: &str| {
        assert!((a - b).abs() <= 1e-6 * b.abs().max(1.0), "{what}: {a} vs {b}")
    };
    let mut mse = vec![vec![0.0; 4]; 5];
    (mse[0][0], mse[1][1], mse[2][3]) = (0.125 * 0.125, 0.25 * 0.25 / 2.0, 0.25);
    assert_eq!(q.mse.len(), 5);
    for (mip, (got, want)) in q.mse.iter().zip(&mse).enumerate() {
        assert_eq!(got.len(), 4, "mip {mip}");
        for c in 0..4 {
            near(got[c], want[c], &format!("MSE of mip {mip} channel {c}"));
        }
    }
    // Squared errors 384 · 0.125² + 48 · 0.25² + 24 · 0.5² = 15 over 511 · 4 samples.
    near(q.psnr, -10.0 * (15.0f64 / 2044.0).log10(), "PSNR of the chain");
    near(psnr(15.0 / 2044.0), q.psnr, "psnr()");
    assert_eq!(psnr(0.0), f64::INFINITY);
    near(q.psnr_of(&[0], Some(0), &set), -10.0 * (0.015625f64).log10(), "channel 0 at mip 0");
    near(q.psnr_of(&[1], None, &set), -10.0 * (3.0f64 / 511.0).log10(), "channel 1, chain");
    near(q.psnr_of(&[0, 1], Some(1), &set), -10.0 * (3.0f64 / 192.0).log10(), "0, 1 at mip 1");
    assert_eq!(q.psnr_of(&[2], None, &set), f64::INFINITY, "an exact channel");
    let mean = [0.125 * 384.0 / 511.0, -0.25 * 48.0 / 511.0, 0.0, -0.5 * 24.0 / 511.0];
    assert_eq!(q.mean_error.len(), 4);
    for (c, (&got, want)) in q.mean_error.iter().zip(mean).enumerate() {
        near(got, want, &format!("mean error of channel {c}"));
    }
    // SSIM at mip 0: 1 for the three exact channels, channel 0's own for the offset one.
    let src0 = &set.mips[0].data;
    let s0 = ssim_channel(src0, &decoded0, 24, 16, 4, 0);
    assert!(s0 < 0.99, "an offset of 0.125 is seen: {s0}");
    near(q.ssim, (s0 + 3.0) / 4.0, "SSIM");
    // Three informative channels (the constant one costs nothing).
    near(q.bppc, bytes.len() as f64 * 8.0 / (24.0 * 16.0 * 3.0), "BPPC");
}

/// SSIM as Wang et al. (2004) define it, written here apart from the encoder's: an 11 × 11
/// Gaussian window (σ = 1.5) normalized to 1, statistics about the window's mean (two passes),
/// K1 = 0.01, K2 = 0.03, dynamic range 1, averaged over the window centres 5 or more texels from
/// every edge (every texel, edges clamped, on a side of 10 or fewer).
fn ssim_reference(a: &[f64], b: &[f64], w: i64, h: i64) -> f64 {
    let (c1, c2) = (0.01f64 * 0.01, 0.03f64 * 0.03);
    let at =
        |img: &[f64], x: i64, y: i64| img[(y.clamp(0, h - 1) * w + x.clamp(0, w - 1)) as usize];
    let centres = |n: i64| if n > 10 { 5..n - 5 } else { 0..n };
    let mut window = Vec::new();
    for dy in -5i64..=5 {
        for dx in -5i64..=5 {
            window.push((dx, dy, (-((dx * dx + dy * dy) as f64) / (2.0 * 1.5 * 1.5)).exp()));
        }
    }
    let total: f64 = window.iter().map(|&(_, _, g)| g).sum();
    let (mut sum, mut count) = (0.0, 0.0);
    for y in centres(h) {
        for x in centres(w) {
            let mean = |img: &[f64]| {
                window.iter().map(|&(dx, dy, g)| g * at(img, x + dx, y + dy)).sum::<f64>() / total
            };
            let (ma, mb) = (mean(a), mean(b));
            let moment = |f: &dyn Fn(i64, i64) -> f64| {
                window.iter().map(|&(dx, dy, g)| g * f(x + dx, y + dy)).sum::<f64>() / total
            };
            let va = moment(&|x, y| (at(a, x, y) - ma).powi(2));
            let vb = moment(&|x, y| (at(b, x, y) - mb).powi(2));
            let cov = moment(&|x, y| (at(a, x, y) - ma) * (at(b, x, y) - mb));
            sum += ((2.0 * ma * mb + c1) * (2.0 * cov + c2))
                / ((ma * ma + mb * mb + c1) * (va + vb + c2));
            count += 1.0;
        }
    }
    sum / count
}

/// SSIM's closed forms (Wang et al. 2004): 1 for equal images, and for two flat images of
/// values a and b, whose variances and covariance are 0, `(2ab + c1) / (a² + b² + c1)`, c1 =
/// 0.01²; and [`ssim_reference`] on noise. On images smaller than the 11 × 11 window too, and
/// 10 × 11 and 11 × 10 (all 10 columns or rows, the one row or column of centres 5 from the
/// edges).
#[test]
fn ssim_has_its_closed_forms() {
    use nmat_encode::metrics::ssim_channel;
    let mut rng = nmat_tests::generate::Rng::new(5);
    for (w, h) in [(20u32, 17u32), (7, 5), (10, 11), (11, 10)] {
        let n = (w * h) as usize * 2;
        let noise: Vec<f32> = (0..n).map(|_| rng.unit() as f32).collect();
        assert_eq!(ssim_channel(&noise, &noise, w, h, 2, 1), 1.0, "{w} × {h}");
        let flat = |v: f32| vec![v; n];
        let (a, b) = (0.5f64, 0.625f64);
        let want = (2.0 * a * b + 1e-4) / (a * a + b * b + 1e-4);
        let got = ssim_channel(&flat(0.5), &flat(0.625), w, h, 2, 0);
        assert!((got - want).abs() < 1e-9, "{w} × {h}: {got} vs {want}");
        // Noise against noise plus noise (channel 1 of 2): the definition itself.
        let other: Vec<f32> = noise.iter().map(|&v| v * 0.7 + rng.unit() as f32 * 0.3).collect();
        let channel =
            |img: &[f32]| img.iter().skip(1).step_by(2).map(|&v| f64::from(v)).collect::<Vec<_>>();
        let want = ssim_reference(&channel(&noise), &channel(&other), w.into(), h.into());
        let got = ssim_channel(&noise, &other, w, h, 2, 1);
        assert!((got - want).abs() < 1e-9, "{w} × {h}: {got} vs the definition's {want}");
        assert!(got < 0.9, "{w} × {h}: {got}");
    }
}
