//! `nmat bench`: the speed–accuracy table of docs/PERFORMANCE.md. For each material, every decode
//! mode runs over the same region of mip 0; a row gives the median time per texel, texels per
//! second, the share of the CPU's arithmetic roofline, PSNR against the source maps (with
//! `--ref`) and the largest difference from the float decoder in 8-bit codes. Reference points
//! measured in the same run: BC1/BC4 decoding (`bcdec_rs`), PNG decoding of the source maps
//! (`image`), and the peak multiply-add rate of every kernel this CPU runs.

use crate::args::{BenchArgs, GpuKernelArg};
use crate::common::{Result, chain_quality_shown, macs, mib, parse};
use crate::reference::{load_reference, warn_if_decoded};
use nmat_cli::input::read_nmat;
use nmat_cli::stats::median;
use nmat_core::{
    ChannelMask, Decoder, Filter, Kernel, Material, Precision, SampleRequest, TexelAt,
};
use nmat_encode::metrics::{psnr, unit_of};
use std::hint::black_box;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// What to measure.
struct Options {
    pub inputs: Vec<PathBuf>,
    pub reference: Option<PathBuf>,
    /// Side of the square region of mip 0 every mode decodes.
    pub region: u32,
    /// Timed runs per row; the median is reported.
    pub runs: usize,
    /// The GPU decoder's table (`--gpu`) instead of the CPU's.
    pub gpu: bool,
    /// With `gpu`: this kernel only (`--kernel`).
    pub kernel: Option<GpuKernelArg>,
    /// No GPU row in the CPU's table (`--cpu-only`).
    pub cpu_only: bool,
    /// Measure against reference maps that do not match the material's channels by role.
    pub force: bool,
    /// Bytes a material's measurement may hold (`--max-memory`).
    pub max_memory: u64,
}

/// One probe of a kernel's peak multiply-add rate (MACs per second), over `macs` multiply-adds.
fn probe_rate(kernel: Kernel, macs: u64) -> Option<f64> {
    let rounds = macs / kernel.probe_macs_per_round().max(1);
    let start = Instant::now();
    black_box(kernel.probe(black_box(rounds))?);
    Some((rounds * kernel.probe_macs_per_round()) as f64 / start.elapsed().as_secs_f64())
}

/// Peak multiply-add rate of a kernel's instruction, in MACs per second (median of 5 probes).
fn peak_rate(kernel: Kernel) -> Option<f64> {
    let rates: Option<Vec<f64>> = (0..5).map(|_| probe_rate(kernel, 256_000_000)).collect();
    Some(median(rates?))
}

/// The median over `runs` of (seconds of `b`) ÷ (seconds of `a`), each run timing `a` then `b`
/// back to back (after one warm-up call of each).
fn interleaved_ratio(runs: usize, a: &mut dyn FnMut(), b: &mut dyn FnMut()) -> f64 {
    a();
    b();
    let mut ratios = Vec::new();
    for _ in 0..runs.max(1) {
        let start = Instant::now();
        a();
        let ta = start.elapsed().as_secs_f64();
        let start = Instant::now();
        b();
        ratios.push(start.elapsed().as_secs_f64() / ta);
    }
    median(ratios)
}

/// A timed mode: the median seconds of its runs, and the median over runs of (seconds × the
/// peak rate measured just before that run): the product the share of the roofline divides.
/// Measuring the peak next to each run keeps the share honest on a shared machine, whose speed
/// drifts between the start of the benchmark and any one row.
#[derive(Clone, Copy)]
struct Timing {
    secs: f64,
    peak_macs: f64,
}

/// `runs` calls of `f` after one warm-up call, each preceded by a short probe of the fastest
/// kernel's peak rate (about a millisecond).
fn time(runs: usize, mut f: impl FnMut()) -> Timing {
    f();
    let (mut secs, mut products) = (Vec::new(), Vec::new());
    for _ in 0..runs.max(1) {
        let peak = probe_rate(Kernel::best(), 64_000_000).unwrap_or(f64::NAN);
        let start = Instant::now();
        f();
        let t = start.elapsed().as_secs_f64();
        secs.push(t);
        products.push(t * peak);
    }
    Timing { secs: median(secs), peak_macs: median(products) }
}

/// One line of the table.
struct Row {
    mode: String,
    seconds_per_texel: f64,
    /// Median over runs of seconds × peak rate, per texel: MACs the peak rate would do.
    peak_macs_per_texel: f64,
    macs_per_texel: f64,
    /// PSNR (dB) of this mode's texels against the source maps, if measurable.
    psnr: Option<f64>,
    /// Largest |difference| from the float decoder, in 8-bit codes.
    max_delta: Option<u32>,
    /// Threads working: the roofline scales with them (one core's peak each).
    threads: usize,
}

/// The benchmark region and what every mode is compared with.
struct Setup<'m, 'a> {
    m: &'m Material<'a>,
    side: (u32, u32),
    /// Float-decoder unit values of the region, `[texel][channel]`.
    float_units: Vec<f32>,
    /// Source unit values of the region, `[texel][channel]`, with `--ref`.
    source: Option<Vec<f32>>,
}

impl Setup<'_, '_> {
    fn texels(&self) -> usize {
        (self.side.0 * self.side.1) as usize
    }

    /// PSNR and max |Δ| of `units` (`[texel][selected channel]`, unit scale) for `channels`.
    fn judge(&self, units: &[f32], channels: &[usize]) -> (Option<f64>, Option<u32>) {
        let c = self.m.channel_count();
        let n = channels.len();
        let code = |u: f32| (u.clamp(0.0, 1.0) * 255.0).round() as i32;
        let mut delta = 0;
        let (mut err, mut count) = (0.0f64, 0usize);
        for (t, texel) in units.chunks_exact(n).enumerate() {
            for (k, &ch) in channels.iter().enumerate() {
                let v = texel[k];
                delta = delta.max(code(v).abs_diff(code(self.float_units[t * c + ch])));
                if let Some(src) = &self.source {
                    let e = f64::from(unit_of(self.m, ch, v) - src[t * c + ch]);
                    err += e * e;
                    count += 1;
                }
            }
        }
        let quality = (count > 0).then(|| psnr(err / count as f64));
        (quality, Some(delta))
    }
}

fn unit_from_range(m: &Material<'_>, ch: usize, v: f32) -> f32 {
    let c = &m.channels()[ch];
    if c.range_max == c.range_min { 0.0 } else { (v - c.range_min) / (c.range_max - c.range_min) }
}

fn channels_of(mask: ChannelMask, count: usize) -> Vec<usize> {
    let bits = mask.resolve(count).unwrap_or(0);
    (0..count).filter(|c| bits & (1 << c) != 0).collect()
}

pub fn run(args: BenchArgs) -> Result<()> {
    let BenchArgs { inputs, reference, region, runs, gpu, kernel, cpu_only, force, memory } = args;
    if region == 0 || runs == 0 {
        return Err("--region and --runs must be at least 1".into());
    }
    let max_memory = memory.bytes();
    let opts =
        Options { inputs, reference, region, runs, gpu, kernel, cpu_only, force, max_memory };
    bench_all(&opts)
}

/// The tables of every material of `opts`.
fn bench_all(opts: &Options) -> Result<()> {
    println!("machine: {}, {} logical CPUs", cpu_name(), std::thread::available_parallelism()?);
    // The GPU table (`--gpu`) has its own peak, measured on the adapter.
    if !opts.gpu {
        for kernel in Kernel::ALL {
            if let Some(rate) = peak_rate(kernel) {
                println!(
                    "  peak multiply-add rate, {:12} {:7.1} GMAC/s",
                    kernel.name(),
                    rate / 1e9
                );
            }
        }
        println!(
            "  roofline = MACs per texel ÷ the {} peak rate per thread; % roofline = roofline time ÷ measured time, each run against the peak measured just before it (median of the runs)\n",
            Kernel::best().name()
        );
    }
    let start = Instant::now();
    for input in &opts.inputs {
        bench_one(input, opts)?;
    }
    if !opts.gpu && opts.inputs.len() > 1 {
        same_run_ratios(opts)?;
    }
    println!("benchmarked in {:.1} s", start.elapsed().as_secs_f64());
    Ok(())
}

/// Each neural file's decode speed against the first file's, timed in alternation (runs of the
/// two back to back, the median of the ratios): the machine's drift, which moves a table's rows
/// between one file and the next by more than a layout changes them, meets both alike. Two
/// modes: the region of mip 0 (1 thread, the best kernel), and random access per texel over
/// the whole of mip 0, where a larger in-memory form would show in cache misses.
fn same_run_ratios(opts: &Options) -> Result<()> {
    let loaded =
        opts.inputs.iter().map(|p| read_nmat(p).map_err(Into::into)).collect::<Result<Vec<_>>>()?;
    let mut materials = Vec::new();
    for (bytes, input) in loaded.iter().zip(&opts.inputs) {
        let m = parse(bytes, input)?;
        if m.jpeg().is_some() {
            println!("same-run ratios: {} is JPEG, left out", input.display());
            continue;
        }
        materials.push((input, m));
    }
    let Some(((first_path, first), rest)) = materials.split_first() else { return Ok(()) };
    if rest.is_empty() {
        return Ok(());
    }
    println!(
        "same run, runs alternated with {} (median of {} ratios); speed ÷ its speed:",
        first_path.display(),
        opts.runs
    );
    let region = |m: &Material<'_>| {
        let (w, h) = m.mip_size(0);
        (opts.region.min(w).max(1), opts.region.min(h).max(1))
    };
    for (path, m) in rest {
        let a = SpeedProbe::new(first, region(first), first.mip_size(0));
        let b = SpeedProbe::new(m, region(m), m.mip_size(0));
        let (mut codes_a, mut codes_b) = (a.codes(), b.codes());
        // interleaved_ratio gives b's seconds ÷ a's; per texel, so regions may differ.
        let per_texel = a.texels() / b.texels();
        let slower = interleaved_ratio(opts.runs, &mut || a.region(&mut codes_a), &mut || {
            b.region(&mut codes_b)
        });
        let region_speed = 1.0 / (slower * per_texel);
        let slower = interleaved_ratio(opts.runs, &mut || a.random(), &mut || b.random());
        let random_speed = 1.0 / (slower * per_texel);
        let (mut batch_a, mut batch_b) = (a.batch(), b.batch());
        let slower =
            interleaved_ratio(opts.runs, &mut || a.random_batched(&mut batch_a), &mut || {
                b.random_batched(&mut batch_b)
            });
        let batched_speed = 1.0 / (slower * per_texel);
        println!(
            "  {:40} region, 1 thread: {region_speed:.3}×   random access over mip 0: \
             {random_speed:.3}× per texel, {batched_speed:.3}× {RANDOM_BATCH} a call",
            path.display().to_string()
        );
    }
    println!();
    Ok(())
}

/// One material's two timed loops with the best kernel, all channels: the region of mip 0 at
/// the origin, row by row, and random access, one call per texel of `scattered`.
struct SpeedProbe<'m, 'a> {
    m: &'m Material<'a>,
    decoder: Decoder,
    side: (u32, u32),
    /// Texels of mip 0 in a scattered order (`scattered_order`).
    scattered: Vec<TexelAt>,
}

impl<'m, 'a> SpeedProbe<'m, 'a> {
    /// Random access scattered over the `area` (width, height) of mip 0 at the origin, as many
    /// texels as the region of `side` has.
    fn new(m: &'m Material<'a>, side: (u32, u32), area: (u32, u32)) -> Self {
        let w = area.0 as usize;
        let n = (side.0 * side.1) as usize;
        let order = scattered_order(w * area.1 as usize);
        let scattered = order.into_iter().take(n).map(|t| texel_at(t, w)).collect();
        SpeedProbe { m, decoder: Decoder::new(m), side, scattered }
    }
    fn texels(&self) -> f64 {
        f64::from(self.side.0) * f64::from(self.side.1)
    }
    /// A buffer for [`SpeedProbe::region`]'s codes.
    fn codes(&self) -> Vec<u8> {
        vec![0u8; self.texels() as usize * self.m.channel_count()]
    }
    /// A buffer for [`SpeedProbe::random_batched`]'s codes.
    fn batch(&self) -> Vec<u8> {
        vec![0u8; RANDOM_BATCH * self.m.channel_count()]
    }
    fn region(&self, codes: &mut [u8]) {
        let w = self.side.0 as usize;
        let row = w * self.m.channel_count();
        for (y, out) in codes.chunks_exact_mut(row).enumerate() {
            let _ = self.decoder.decode_span_u8(self.m, 0, y as i64, 0, w, ChannelMask::ALL, out);
        }
    }
    fn random(&self) {
        let mut texel = [0u8; 16];
        for t in &self.scattered {
            let _ = self.decoder.decode_texel_u8(self.m, t.x, t.y, 0, ChannelMask::ALL, &mut texel);
            black_box(&texel);
        }
    }
    /// [`SpeedProbe::random`]'s texels, [`RANDOM_BATCH`] a call.
    fn random_batched(&self, batch: &mut [u8]) {
        for texels in self.scattered.chunks(RANDOM_BATCH) {
            let _ = self.decoder.decode_texels_u8(self.m, texels, ChannelMask::ALL, batch);
            black_box(&batch);
        }
    }
}

fn cpu_name() -> String {
    std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split(':').nth(1))
                .map(|s| s.trim().to_string())
        })
        .unwrap_or_else(|| std::env::consts::ARCH.to_string())
}

fn bench_one(input: &Path, opts: &Options) -> Result<()> {
    let bytes = read_nmat(input)?;
    let m = parse(&bytes, input)?;
    let (w, h) = m.mip_size(0);
    let side = (opts.region.min(w).max(1), opts.region.min(h).max(1));
    check_memory(input, &m, side, opts)?;
    if opts.gpu {
        println!(
            "{}: {w}×{h}, {} channels, {} mips, {} bytes, {} MACs/texel",
            input.display(),
            m.channel_count(),
            m.mip_count(),
            bytes.len(),
            macs(&m, m.channel_count())
        );
        return crate::gpu::bench_table(&m, opts.region, opts.runs, opts.kernel);
    }
    let c = m.channel_count();
    let best = Decoder::new(&m);
    let float_units = region_float_units(&m, &best, side);
    let (source, chain_psnr, png) = match &opts.reference {
        Some(dir) => {
            let set = load_reference(&m, dir, opts.force, opts.max_memory)?;
            let src = &set.mips[0];
            let mut region = Vec::with_capacity((side.0 * side.1) as usize * c);
            for y in 0..side.1 {
                let at = (y * src.width) as usize * c;
                region.extend_from_slice(&src.data[at..at + side.0 as usize * c]);
            }
            let quality = chain_quality_shown(&m, &set);
            warn_if_decoded(&quality, dir);
            (Some(region), Some(quality.psnr), png_seconds(&m, dir, opts.runs)?)
        }
        None => (None, None, None),
    };
    let setup = Setup { m: &m, side, float_units, source };
    println!(
        "{}: {w}×{h}, {c} channels, {} bytes ({:.3} BPPC{}), {} MACs/texel, kernel {}{}",
        input.display(),
        bytes.stored.len,
        m.bppc_of(bytes.stored.len),
        if bytes.stored.packed { format!("; {:.3} in memory", m.bppc()) } else { String::new() },
        macs(&m, c),
        best.kernel().name(),
        chain_psnr.map_or(String::new(), |p| format!(", whole-chain PSNR {p:.2} dB (integer)")),
    );
    println!("  region {}×{} of mip 0, median of {} runs", side.0, side.1, opts.runs);
    if bytes.stored.packed {
        let raw = nmat_cli::input::read_raw(input)?;
        let options = nmat_core::ParseOptions::default();
        let seconds = nmat_cli::stats::median_seconds(opts.runs, || {
            nmat_core::unpack(black_box(&raw), options).map(|u| drop(black_box(u)))
        })?;
        println!(
            "  unpacking at load ({}, checksum included): {:.1} ms, once per open",
            if m.jpeg().is_some() { "the index rebuilt" } else { "entropy-coded latents" },
            seconds * 1e3
        );
    }
    let mut rows = Vec::new();
    let mut notes = Vec::new();
    region_rows(&setup, opts.runs, &mut rows, &mut notes);
    filter_rows(&setup, opts.runs, &mut rows);
    print_rows(&rows, bytes.len());
    for note in &notes {
        println!("  {note}");
    }
    reference_rows(&setup, &float_units_to_codes(&setup.float_units), opts.runs, png);
    if opts.cpu_only {
        println!("  GPU: not measured (--cpu-only)");
    } else {
        crate::gpu::bench_row(&m, side, &|name, secs, texels, scope| {
            let texels = texels as f64;
            println!(
                "  {name:52} {:9.1} ns/texel {:12.0} texels/s ({scope})",
                secs * 1e9 / texels,
                texels / secs
            );
        })?;
    }
    println!();
    Ok(())
}

/// Refuses a measurement of `m` whose buffers would exceed `--max-memory`, before any is
/// allocated: per texel-channel of the region the float decode, the source, the codes of a mode
/// and its float output; with the `gpu` feature the codes of the whole chain (the GPU row reads
/// mip 0 back, `--gpu` the chain), unless `--cpu-only`.
fn check_memory(input: &Path, m: &Material<'_>, side: (u32, u32), opts: &Options) -> Result<()> {
    let max_memory = opts.max_memory;
    let c = m.channel_count() as u64;
    let region = u64::from(side.0) * u64::from(side.1) * c * 16;
    let chain: u64 = (0..m.mip_count()).map(|i| m.decode_cost(i).texels).sum();
    let gpu = if crate::gpu::BUILT && !opts.cpu_only { chain * c } else { 0 };
    let need = region + gpu;
    if need > max_memory {
        return Err(format!(
            "{}: measuring a {}×{} region (--region) needs about {:.1} MiB, more than the {:.1} \
             MiB allowed; nothing was measured. Lower --region or raise --max-memory",
            input.display(),
            side.0,
            side.1,
            mib(need),
            mib(max_memory)
        )
        .into());
    }
    Ok(())
}

fn region_float_units(m: &Material<'_>, d: &Decoder, side: (u32, u32)) -> Vec<f32> {
    let c = m.channel_count();
    let mut out = vec![0f32; (side.0 * side.1) as usize * c];
    for (y, row) in out.chunks_exact_mut(side.0 as usize * c).enumerate() {
        let _ = d.decode_span_f32(m, 0, y as i64, 0, side.0 as usize, ChannelMask::ALL, row);
    }
    for (i, v) in out.iter_mut().enumerate() {
        *v = unit_from_range(m, i % c, *v);
    }
    out
}

fn float_units_to_codes(units: &[f32]) -> Vec<u8> {
    units.iter().map(|&u| (u.clamp(0.0, 1.0) * 255.0).round() as u8).collect()
}

/// Decodes the region with `decode_row(y, row_out)` (u8 codes), timed; returns (seconds, codes).
fn time_codes(
    setup: &Setup<'_, '_>,
    n: usize,
    runs: usize,
    threads: usize,
    decode_row: &(dyn Fn(u32, &mut [u8]) + Sync),
) -> (Timing, Vec<f32>) {
    let (w, h) = setup.side;
    let mut codes = vec![0u8; (w * h) as usize * n];
    let row_len = w as usize * n;
    let secs = time(runs, || {
        if threads <= 1 {
            for (y, row) in codes.chunks_exact_mut(row_len).enumerate() {
                decode_row(y as u32, row);
            }
        } else {
            let rows_per = (h as usize).div_ceil(threads);
            std::thread::scope(|s| {
                for (part, chunk) in codes.chunks_mut(rows_per * row_len).enumerate() {
                    s.spawn(move || {
                        for (i, row) in chunk.chunks_exact_mut(row_len).enumerate() {
                            decode_row((part * rows_per + i) as u32, row);
                        }
                    });
                }
            });
        }
    });
    (secs, codes.iter().map(|&v| f32::from(v) / 255.0).collect())
}

fn region_rows(setup: &Setup<'_, '_>, runs: usize, rows: &mut Vec<Row>, notes: &mut Vec<String>) {
    if setup.m.jpeg().is_some() {
        return jpeg_rows(setup, runs, rows, notes);
    }
    let m = setup.m;
    let c = m.channel_count();
    let texels = setup.texels() as f64;
    let (w, _) = setup.side;
    let all: Vec<usize> = (0..c).collect();
    let threads_now = std::cell::Cell::new(1);
    let mut push = |mode: String, t: Timing, outputs: usize, units: &[f32], chans: &[usize]| {
        let (psnr, max_delta) = setup.judge(units, chans);
        let threads = threads_now.get();
        rows.push(Row {
            mode,
            seconds_per_texel: t.secs / texels,
            peak_macs_per_texel: t.peak_macs / texels,
            macs_per_texel: macs(m, outputs) as f64,
            psnr,
            max_delta,
            threads,
        });
    };
    let best = Decoder::new(m);
    let masks: Vec<(String, ChannelMask)> = {
        let mut v = vec![(format!("all {c}"), ChannelMask::ALL)];
        if c > 3 {
            v.push(("3".into(), ChannelMask(0b111)));
        }
        if c > 1 {
            v.push(("1".into(), ChannelMask::single(0)));
        }
        v
    };
    // Integer, batched region, every kernel, all channels, 1 thread.
    for kernel in Kernel::ALL.into_iter().filter(|k| k.is_available()).rev() {
        let Ok(d) = Decoder::with_kernel(m, kernel) else { continue };
        let (secs, units) = time_codes(setup, c, runs, 1, &|y, row| {
            let _ = d.decode_span_u8(m, 0, i64::from(y), 0, w as usize, ChannelMask::ALL, row);
        });
        push(
            format!("integer {} region, all {c} ch, 1 thread", kernel.name()),
            secs,
            c,
            &units,
            &all,
        );
    }
    let kernel = best.kernel().name();
    // Channel subsets and 2 threads with the best kernel.
    for (label, mask) in masks.iter().skip(1) {
        let chans = channels_of(*mask, c);
        let n = chans.len();
        let (secs, units) = time_codes(setup, n, runs, 1, &|y, row| {
            let _ = best.decode_span_u8(m, 0, i64::from(y), 0, w as usize, *mask, row);
        });
        push(format!("integer {kernel} region, {label} ch, 1 thread"), secs, n, &units, &chans);
    }
    let (secs, units) = time_codes(setup, c, runs, 2, &|y, row| {
        let _ = best.decode_span_u8(m, 0, i64::from(y), 0, w as usize, ChannelMask::ALL, row);
    });
    threads_now.set(2);
    push(format!("integer {kernel} region, all {c} ch, 2 threads"), secs, c, &units, &all);
    threads_now.set(1);
    // Random access: the same texels in a scattered order, one call each.
    let order = scattered_order(setup.texels());
    let (secs, units) = time_random(setup, runs, &order, &|x, y, out| {
        let _ = best.decode_texel_u8(m, x, y, 0, ChannelMask::ALL, out);
    });
    push(format!("integer {kernel} random access per texel, all {c} ch"), secs, c, &units, &all);
    let (secs, units) = time_random_batched(setup, runs, &order, &best);
    push(
        format!("integer {kernel} random access, {RANDOM_BATCH} a call, all {c} ch"),
        secs,
        c,
        &units,
        &all,
    );
    // Random access and region decode, timed in alternation so that both meet the same machine.
    let probe = SpeedProbe::new(m, setup.side, setup.side);
    let mut codes = probe.codes();
    let ratio = interleaved_ratio(runs, &mut || probe.region(&mut codes), &mut || probe.random());
    notes.push(format!(
        "random access ÷ region per texel, {kernel}, runs alternated: {ratio:.2}× (median of {runs})"
    ));
    let mut batch = probe.batch();
    let ratio =
        interleaved_ratio(runs, &mut || probe.random(), &mut || probe.random_batched(&mut batch));
    notes.push(format!(
        "random access {RANDOM_BATCH} a call ÷ one call a texel, {kernel}, runs alternated: \
         {ratio:.2}× (median of {runs})"
    ));
    let (secs, units) = time_random(setup, runs, &order, &|x, y, out| {
        let _ = m.decode_texel_u8(x, y, 0, ChannelMask::ALL, out);
    });
    push(format!("integer per-texel definition (Material), all {c} ch"), secs, c, &units, &all);
    // Float: prepared f32 weights vs int8 weights dequantized at every use.
    let mut floats = vec![0f32; setup.texels() * c];
    let secs = time(runs, || {
        for (y, row) in floats.chunks_exact_mut(w as usize * c).enumerate() {
            let _ = best.decode_span_f32(m, 0, y as i64, 0, w as usize, ChannelMask::ALL, row);
        }
    });
    let units: Vec<f32> =
        floats.iter().enumerate().map(|(i, &v)| unit_from_range(m, i % c, v)).collect();
    push(format!("float, f32 weights (Decoder) region, all {c} ch"), secs, c, &units, &all);
    let secs = time(runs, || {
        for (t, texel) in floats.chunks_exact_mut(c).enumerate() {
            let (x, y) = ((t % w as usize) as i64, (t / w as usize) as i64);
            let _ = m.decode_texel(x, y, 0, ChannelMask::ALL, texel);
        }
    });
    let units: Vec<f32> =
        floats.iter().enumerate().map(|(i, &v)| unit_from_range(m, i % c, v)).collect();
    push(
        format!("float, dequantized at use (Material) per texel, all {c} ch"),
        secs,
        c,
        &units,
        &all,
    );
}

/// The rows of a JPEG material (no network, no kernels): the region path (each MCU decoded
/// once) on 1 and 2 threads and for one channel, row spans (each MCU decoded once per row), and
/// random access (a whole MCU per texel).
fn jpeg_rows(setup: &Setup<'_, '_>, runs: usize, rows: &mut Vec<Row>, notes: &mut Vec<String>) {
    let m = setup.m;
    let c = m.channel_count();
    let texels = setup.texels() as f64;
    let (w, h) = setup.side;
    let all: Vec<usize> = (0..c).collect();
    let mut push = |mode: String, t: Timing, threads: usize, units: &[f32], chans: &[usize]| {
        let (psnr, max_delta) = setup.judge(units, chans);
        rows.push(Row {
            mode,
            seconds_per_texel: t.secs / texels,
            peak_macs_per_texel: t.peak_macs / texels,
            macs_per_texel: 0.0,
            psnr,
            max_delta,
            threads,
        });
    };
    let d = Decoder::new(m);
    let units = |codes: &[u8]| codes.iter().map(|&v| f32::from(v) / 255.0).collect::<Vec<f32>>();
    // The region in bands of whole MCU rows, split between `threads`.
    let region = |threads: usize, mask: ChannelMask, out: &mut [u8]| {
        let n = out.len() / setup.texels().max(1);
        if threads <= 1 {
            let _ = d.decode_region_u8(m, 0, (0, 0, w, h), mask, out, 0);
            return;
        }
        let band = (h as usize).div_ceil(threads).next_multiple_of(16);
        std::thread::scope(|s| {
            for (k, part) in out.chunks_mut(band * w as usize * n).enumerate() {
                let d = &d;
                s.spawn(move || {
                    let rows = (part.len() / (w as usize * n).max(1)) as u32;
                    let rect = (0, (k * band) as u32, w, rows);
                    let _ = d.decode_region_u8(m, 0, rect, mask, part, 0);
                });
            }
        });
    };
    for (threads, mask, chans) in [
        (1, ChannelMask::ALL, all.clone()),
        (2, ChannelMask::ALL, all.clone()),
        (1, ChannelMask::single(0), vec![0]),
    ] {
        if c == 1 && mask != ChannelMask::ALL {
            continue;
        }
        let mut codes = vec![0u8; setup.texels() * chans.len()];
        let secs = time(runs, || region(threads, mask, &mut codes));
        let thread_word = if threads == 1 { "thread" } else { "threads" };
        let label = format!(
            "JPEG region (each MCU once), {} ch, {threads} {thread_word}",
            if chans.len() == c { format!("all {c}") } else { chans.len().to_string() }
        );
        push(label, secs, threads, &units(&codes), &chans);
    }
    let (secs, span_units) = time_codes(setup, c, runs, 1, &|y, row| {
        let _ = d.decode_span_u8(m, 0, i64::from(y), 0, w as usize, ChannelMask::ALL, row);
    });
    push(
        format!("JPEG row spans (an MCU per row), all {c} ch, 1 thread"),
        secs,
        1,
        &span_units,
        &all,
    );
    let order = scattered_order(setup.texels());
    let (secs, random_units) = time_random(setup, runs, &order, &|x, y, out| {
        let _ = d.decode_texel_u8(m, x, y, 0, ChannelMask::ALL, out);
    });
    push(
        format!("JPEG random access per texel (an MCU each), all {c} ch"),
        secs,
        1,
        &random_units,
        &all,
    );
    let mut codes = vec![0u8; setup.texels() * c];
    let ratio =
        interleaved_ratio(runs, &mut || region(1, ChannelMask::ALL, &mut codes), &mut || {
            let mut texel = [0u8; 16];
            for &t in &order {
                let (x, y) = ((t % w as usize) as i64, (t / w as usize) as i64);
                let _ = d.decode_texel_u8(m, x, y, 0, ChannelMask::ALL, &mut texel);
                black_box(&texel);
            }
        });
    notes.push(format!(
        "random access ÷ region per texel, JPEG, runs alternated: {ratio:.2}× (median of {runs})"
    ));
}

/// A permutation of 0..n that jumps around (multiplicative stride coprime with n).
fn scattered_order(n: usize) -> Vec<usize> {
    let mut stride = 7919 % n.max(1);
    while stride > 1 && gcd(stride, n) != 1 {
        stride += 1;
    }
    (0..n).map(|i| (i * stride.max(1)) % n.max(1)).collect()
}

fn gcd(a: usize, b: usize) -> usize {
    if b == 0 { a } else { gcd(b, a % b) }
}

fn time_random(
    setup: &Setup<'_, '_>,
    runs: usize,
    order: &[usize],
    decode: &dyn Fn(i64, i64, &mut [u8]),
) -> (Timing, Vec<f32>) {
    let c = setup.m.channel_count();
    let w = setup.side.0 as usize;
    let mut codes = vec![0u8; setup.texels() * c];
    let secs = time(runs, || {
        for &t in order {
            decode((t % w) as i64, (t / w) as i64, &mut codes[t * c..(t + 1) * c]);
        }
    });
    (secs, codes.iter().map(|&v| f32::from(v) / 255.0).collect())
}

/// Texel `t` of mip 0, counted row by row in rows of `width` texels.
fn texel_at(t: usize, width: usize) -> TexelAt {
    TexelAt { x: (t % width) as i64, y: (t / width) as i64, mip: 0 }
}

/// Texels of a batched random-access call (`Decoder::decode_texels_u8`) in the benchmarks.
const RANDOM_BATCH: usize = 256;

/// [`time_random`] through `Decoder::decode_texels_u8`, [`RANDOM_BATCH`] texels of `order` a call.
fn time_random_batched(
    setup: &Setup<'_, '_>,
    runs: usize,
    order: &[usize],
    decoder: &Decoder,
) -> (Timing, Vec<f32>) {
    let (m, c) = (setup.m, setup.m.channel_count());
    let w = setup.side.0 as usize;
    let texels: Vec<TexelAt> = order.iter().map(|&t| texel_at(t, w)).collect();
    let mut batch = vec![0u8; RANDOM_BATCH * c];
    let mut codes = vec![0u8; setup.texels() * c];
    let secs = time(runs, || {
        for (ts, order) in texels.chunks(RANDOM_BATCH).zip(order.chunks(RANDOM_BATCH)) {
            let _ = decoder.decode_texels_u8(m, ts, ChannelMask::ALL, &mut batch);
            for (&t, texel) in order.iter().zip(batch.chunks_exact(c)) {
                codes[t * c..(t + 1) * c].copy_from_slice(texel);
            }
        }
    });
    (secs, codes.iter().map(|&v| f32::from(v) / 255.0).collect())
}

fn filter_rows(setup: &Setup<'_, '_>, runs: usize, rows: &mut Vec<Row>) {
    let m = setup.m;
    let c = m.channel_count();
    let w = setup.side.0;
    let (mw, mh) = m.mip_size(0);
    let texels = setup.texels() as f64;
    for (filter, lod, taps) in [
        (Filter::Nearest, 0.0, 1.0),
        (Filter::Stochastic, 0.5, 1.0),
        (Filter::Bilinear, 0.0, 4.0),
        (Filter::Trilinear, 0.5, 8.0),
    ] {
        let request = |x: u32, y: u32, precision| {
            // A quarter texel off the centre, so bilinear footprints have 4 non-zero taps.
            let (u, v) = ((x as f32 + 0.75) / mw as f32, (y as f32 + 0.75) / mh as f32);
            let r =
                ((x.wrapping_mul(2_654_435_761) ^ y.wrapping_mul(40_503)) % 1000) as f32 / 1000.0;
            SampleRequest {
                u,
                v,
                lod,
                filter,
                precision,
                random: [r, 1.0 - r, (r * 7.0).fract()],
                channels: ChannelMask::ALL,
            }
        };
        let decoder = Decoder::new(m);
        let decode_all = |precision| {
            let mut out = vec![0f32; setup.texels() * c];
            let secs = time(runs, || {
                for (t, texel) in out.chunks_exact_mut(c).enumerate() {
                    let (x, y) = (t as u32 % w, t as u32 / w);
                    let _ = decoder.sample(m, &request(x, y, precision), texel);
                }
            });
            (secs, out)
        };
        let (timing, ints) = decode_all(Precision::Integer);
        let (_, floats) = decode_all(Precision::Float);
        let delta = ints
            .iter()
            .zip(&floats)
            .enumerate()
            .map(|(i, (&a, &b))| {
                let code =
                    |v| (unit_from_range(m, i % c, v).clamp(0.0, 1.0) * 255.0).round() as i32;
                code(a).abs_diff(code(b))
            })
            .max();
        rows.push(Row {
            mode: format!(
                "sample {filter:?} (lod {lod}), integer, {} per texel",
                decoder.kernel().name()
            ),
            seconds_per_texel: timing.secs / texels,
            peak_macs_per_texel: timing.peak_macs / texels,
            macs_per_texel: macs(m, c) as f64 * taps,
            psnr: None,
            max_delta: delta,
            threads: 1,
        });
    }
}

fn print_rows(rows: &[Row], bytes: usize) {
    println!(
        "  {:52} {:>10} {:>12} {:>9} {:>8} {:>9} {:>7}",
        "mode", "ns/texel", "texels/s", "%roofline", "PSNR dB", "max|Δ|", "bytes"
    );
    for r in rows {
        println!(
            "  {:52} {:10.1} {:12.0} {:8.1}% {:>8} {:>9} {:>7}",
            r.mode,
            r.seconds_per_texel * 1e9,
            1.0 / r.seconds_per_texel,
            100.0 * r.macs_per_texel / (r.peak_macs_per_texel * r.threads as f64),
            r.psnr.map_or("—".into(), |p| format!("{p:.2}")),
            r.max_delta.map_or("—".into(), |d| d.to_string()),
            bytes,
        );
    }
}

/// BC1/BC4 decoding of the same region (the material's float decode, BC-compressed by a simple
/// min/max block encoder: decode speed does not depend on the encoder), and PNG decoding.
fn reference_rows(setup: &Setup<'_, '_>, codes: &[u8], runs: usize, png: Option<(f64, u64)>) {
    let c = setup.m.channel_count();
    let (w, h) = (setup.side.0 as usize & !3, setup.side.1 as usize & !3);
    if w >= 4 && h >= 4 {
        let (bc1, bc4) = (c / 3, c % 3);
        let mut textures: Vec<(bool, Vec<u8>)> = Vec::new();
        for t in 0..bc1 {
            textures.push((true, encode_bc(codes, setup.side.0 as usize, c, 3 * t, 3, (w, h))));
        }
        for k in 0..bc4 {
            textures
                .push((false, encode_bc(codes, setup.side.0 as usize, c, 3 * bc1 + k, 1, (w, h))));
        }
        let mut rgba = vec![0u8; w * h * 4];
        let mut gray = vec![0u8; w * h];
        let secs = time(runs, || {
            for (is_bc1, blocks) in &textures {
                for (b, block) in blocks.chunks_exact(8).enumerate() {
                    let (bx, by) = (b % (w / 4), b / (w / 4));
                    if *is_bc1 {
                        let at = (by * 4 * w + bx * 4) * 4;
                        bcdec_rs::bc1(block, &mut rgba[at..], w * 4);
                    } else {
                        let at = by * 4 * w + bx * 4;
                        bcdec_rs::bc4(block, &mut gray[at..], w, false);
                    }
                }
            }
            black_box((&rgba, &gray));
        });
        let per = secs.secs / (w * h) as f64;
        println!(
            "  {:52} {:10.1} {:12.0}   ({bc1}× BC1 + {bc4}× BC4 for {c} channels, 4 bits/texel each)",
            "reference: BC1/BC4 decode (bcdec_rs), all channels",
            per * 1e9,
            1.0 / per
        );
    }
    if let Some((secs, texels)) = png {
        let per = secs / texels as f64;
        println!(
            "  {:52} {:10.1} {:12.0}   (every source map, whole mip 0)",
            "reference: PNG decode of the source maps (image)",
            per * 1e9,
            1.0 / per
        );
    }
}

/// BC1 (3 channels from `first`) or BC4 (1 channel) blocks of a `w × h` area: endpoints at the
/// block's per-channel min and max, indices to the nearest palette entry.
fn encode_bc(
    codes: &[u8],
    stride_w: usize,
    c: usize,
    first: usize,
    n: usize,
    (w, h): (usize, usize),
) -> Vec<u8> {
    let mut out = Vec::with_capacity(w * h / 2);
    for by in (0..h).step_by(4) {
        for bx in (0..w).step_by(4) {
            let texel =
                |i: usize, k: usize| codes[((by + i / 4) * stride_w + bx + i % 4) * c + first + k];
            if n == 3 {
                let luma = |i: usize| (0..3).map(|k| u32::from(texel(i, k))).sum::<u32>();
                let (lo, hi) = (
                    (0..16).min_by_key(|&i| luma(i)).unwrap_or(0),
                    (0..16).max_by_key(|&i| luma(i)).unwrap_or(0),
                );
                let rgb565 = |i: usize| {
                    (u16::from(texel(i, 0)) >> 3) << 11
                        | (u16::from(texel(i, 1)) >> 2) << 5
                        | u16::from(texel(i, 2)) >> 3
                };
                // Four-colour mode needs c0 > c1; palette 0 = c0, 1 = c1, 2 = ⅔c0 + ⅓c1, 3 = ⅓c0 + ⅔c1.
                let (h565, l565) = (rgb565(hi), rgb565(lo));
                let (c0, c1, hi_first) =
                    if h565 >= l565 { (h565, l565, true) } else { (l565, h565, false) };
                let span = luma(hi).saturating_sub(luma(lo)).max(1);
                let mut idx = 0u32;
                for i in 0..16 {
                    let t = ((luma(i).saturating_sub(luma(lo)) * 3 + span / 2) / span).min(3); // 0 = lo … 3 = hi
                    let from_c0 = if hi_first { 3 - t } else { t }; // thirds of the way from c0 to c1
                    let sel = if c0 == c1 { 0 } else { [0u32, 2, 3, 1][from_c0 as usize] };
                    idx |= sel << (2 * i);
                }
                out.extend_from_slice(&c0.to_le_bytes());
                out.extend_from_slice(&c1.to_le_bytes());
                out.extend_from_slice(&idx.to_le_bytes());
            } else {
                let (lo, hi) = (
                    (0..16).map(|i| texel(i, 0)).min().unwrap_or(0),
                    (0..16).map(|i| texel(i, 0)).max().unwrap_or(0),
                );
                let span = u32::from(hi - lo).max(1);
                let mut idx = 0u64;
                for i in 0..16 {
                    let t = (u32::from(texel(i, 0) - lo) * 7 + span / 2) / span; // 0 = lo … 7 = hi
                    let sel = match t {
                        0 => 1,
                        7 => 0,
                        t => 8 - t,
                    };
                    idx |= u64::from(sel) << (3 * i);
                }
                out.push(hi);
                out.push(lo);
                out.extend_from_slice(&idx.to_le_bytes()[..6]);
            }
        }
    }
    out
}

/// Median seconds to decode every source map of `m` found in `dir`, and the texels of mip 0.
fn png_seconds(m: &Material<'_>, dir: &Path, runs: usize) -> Result<Option<(f64, u64)>> {
    let Some(maps) = nmat_cli::output::source_maps(m) else { return Ok(None) };
    let files: Vec<PathBuf> =
        maps.iter().map(|s| dir.join(&s.file_name)).filter(|p| p.is_file()).collect();
    if files.is_empty() {
        return Ok(None);
    }
    // The maps as PNG files in memory (the dev set ships TGA): what a PNG-shipping game loads.
    let mut contents = Vec::new();
    for file in &files {
        let image = image::open(file).map_err(|e| format!("{}: {e}", file.display()))?;
        let mut png = std::io::Cursor::new(Vec::new());
        image.write_to(&mut png, image::ImageFormat::Png)?;
        contents.push(png.into_inner());
    }
    let secs = time(runs, || {
        for bytes in &contents {
            black_box(image::load_from_memory_with_format(bytes, image::ImageFormat::Png).ok());
        }
    });
    let (w, h) = m.mip_size(0);
    Ok(Some((secs.secs, u64::from(w) * u64::from(h))))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The BC encoder's blocks decode back close to flat inputs (checks the index mapping: a
    /// wrong palette order would decode a flat block to another value).
    #[test]
    fn bc_blocks_of_flat_and_two_level_blocks_decode_to_their_values() {
        let (w, h, c) = (8usize, 4usize, 4usize);
        let mut codes = vec![0u8; w * h * c];
        for (i, t) in codes.chunks_exact_mut(c).enumerate() {
            let v = if i % w < 4 {
                [200, 100, 40, 77]
            } else if (i / w) % 2 == 0 {
                [8, 16, 248, 10]
            } else {
                [248, 240, 8, 250]
            };
            t.copy_from_slice(&v);
        }
        let bc1 = encode_bc(&codes, w, c, 0, 3, (w, h));
        let bc4 = encode_bc(&codes, w, c, 3, 1, (w, h));
        let mut rgba = [0u8; 64];
        bcdec_rs::bc1(&bc1[0..8], &mut rgba, 16);
        assert!(
            rgba.chunks(4).all(|p| p[0].abs_diff(200) <= 8
                && p[1].abs_diff(100) <= 4
                && p[2].abs_diff(40) <= 8)
        );
        let mut gray = [0u8; 16];
        bcdec_rs::bc4(&bc4[8..16], &mut gray, 4, false);
        assert_eq!(gray[..4], [10; 4]);
        assert_eq!(gray[4..8], [250; 4]);
        assert!(
            scattered_order(1000).iter().copied().collect::<std::collections::BTreeSet<_>>().len()
                == 1000
        );
    }
}
