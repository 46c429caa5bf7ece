//! `nmat build MANIFEST`: every material of a manifest (`nmat_cli::manifest`), each by its own
//! `nmat encode` process (the same command line a build file would run), several at a time;
//! outputs whose inputs, options and encoder are unchanged are kept; one failure does not stop
//! the others; a summary (CSV or JSON) of every material at the end.

use crate::args::{BuildArgs, EmitArg};
use crate::common::Result;
use nmat_cli::manifest::{self, Job};
use nmat_cli::output;
use nmat_cli::report::{self, LibraryRow, PlotPoint};
use serde::{Deserialize, Serialize};
use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::Mutex;
use std::time::Instant;

/// What a build of one material produced, kept next to its output (`OUTPUT.build`) so a later
/// build knows it is up to date and can report it.
#[derive(Clone, Debug, Default, Deserialize, Serialize)]
struct Record {
    /// [`manifest::build_key`] of what it was built from.
    key: String,
    bppc: f64,
    psnr_db: f64,
    ssim: f64,
    /// Whole-chain PSNR per source map.
    maps: Vec<MapQuality>,
    seconds: f64,
}

#[derive(Clone, Debug, Default, Deserialize, Serialize)]
struct MapQuality {
    map: String,
    psnr_db: f64,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
enum Status {
    Built,
    Cached,
    Failed,
}

#[derive(Debug, Serialize)]
struct Outcome {
    material: String,
    input: PathBuf,
    output: PathBuf,
    status: Status,
    #[serde(flatten)]
    record: Record,
    /// Why it failed (the last lines of its log).
    error: String,
    log: PathBuf,
}

pub fn run(args: BuildArgs) -> Result<()> {
    let start = Instant::now();
    let all = manifest::load(&args.manifest)?;
    let (k, n) = match &args.shard {
        Some(s) => manifest::parse_shard(s)?,
        None => (1, 1),
    };
    let jobs: Vec<Job> = all.into_iter().filter(|j| manifest::in_shard(j, k, n)).collect();
    if let (Some(kind), Some(path)) = (args.emit, &args.output) {
        return emit(kind, path, &args.manifest, &jobs);
    }
    let cores = std::thread::available_parallelism().map_or(1, |c| c.get());
    let workers = args.jobs.unwrap_or(cores);
    if workers == 0 || workers > 4 * cores {
        return Err(format!(
            "--jobs {workers}: give 1 to {} (4 × this machine's cores)",
            4 * cores
        )
        .into());
    }
    let summary =
        args.summary.clone().unwrap_or_else(|| args.manifest.with_extension("summary.csv"));
    output::check_output_file("--summary", &summary, std::slice::from_ref(&args.manifest))?;
    let page = summary.with_extension("html");
    if args.report {
        output::check_output_file("--report", &page, std::slice::from_ref(&args.manifest))?;
    }
    // Read before any work: a bad anchors file is an error before the first encode.
    let anchors = match &args.anchors {
        Some(path) => report::read_anchor_rows(path)?,
        None => Vec::new(),
    };
    let exe = std::env::current_exe().map_err(|e| format!("this program's path: {e}"))?;
    // The encoder's identity: this very binary (a rebuilt nmat may encode differently).
    let version = format!(
        "nmat {} {:016x}",
        env!("CARGO_PKG_VERSION"),
        manifest::fnv1a(&std::fs::read(&exe).map_err(|e| format!("{}: {e}", exe.display()))?)
    );
    let threads = (cores / workers.min(jobs.len().max(1))).max(1);
    eprintln!(
        "nmat build: {} materials{}, {workers} at a time, {threads} thread(s) each",
        jobs.len(),
        if n > 1 { format!(" (shard {k}/{n})") } else { String::new() }
    );
    let total = jobs.len();
    let queue = Mutex::new(jobs.into_iter().collect::<VecDeque<Job>>());
    let outcomes = Mutex::new(Vec::new());
    std::thread::scope(|s| {
        for _ in 0..workers {
            s.spawn(|| {
                while let Some(job) = queue.lock().ok().and_then(|mut q| q.pop_front()) {
                    let mut outcome = build_one(&job, &exe, &version, threads, args.force);
                    if args.report
                        && outcome.status != Status::Failed
                        && let Err(e) = report(&job, &exe)
                    {
                        outcome.status = Status::Failed;
                        outcome.error = e;
                    }
                    let mut done = match outcomes.lock() {
                        Ok(d) => d,
                        Err(poisoned) => poisoned.into_inner(),
                    };
                    eprintln!("[{}/{total}] {}", done.len() + 1, line(&outcome));
                    done.push(outcome);
                }
            });
        }
    });
    let mut outcomes = outcomes.into_inner().unwrap_or_else(|p| p.into_inner());
    outcomes.sort_by(|a, b| a.output.cmp(&b.output));
    write_summary(&summary, &outcomes)?;
    if args.report {
        let html = library_page(&args.manifest, &page, &outcomes, &anchors);
        output::write_atomic(&page, html.as_bytes())?;
        eprintln!("nmat build: report {}", page.display());
    }
    let count = |s: Status| outcomes.iter().filter(|o| o.status == s).count();
    println!(
        "nmat build: {} built, {} up to date, {} failed in {:.1} s; summary {}",
        count(Status::Built),
        count(Status::Cached),
        count(Status::Failed),
        start.elapsed().as_secs_f64(),
        summary.display()
    );
    let failed: Vec<String> = outcomes
        .iter()
        .filter(|o| o.status == Status::Failed)
        .map(|o| format!("{} (log {})", o.material, o.log.display()))
        .collect();
    if !failed.is_empty() {
        return Err(format!("{} material(s) failed: {}", failed.len(), failed.join(", ")).into());
    }
    Ok(())
}

/// The build's page ([`report::library_page`]) at `page`: every material, and a plot for each
/// folder with more than one output built or with rows in `anchors`.
fn library_page(
    manifest: &Path,
    page: &Path,
    outcomes: &[Outcome],
    anchors: &[(String, PlotPoint)],
) -> String {
    let from = page.parent().unwrap_or(Path::new("."));
    let from = if from.as_os_str().is_empty() { Path::new(".") } else { from };
    let rows: Vec<LibraryRow> = outcomes
        .iter()
        .map(|o| {
            let html = beside(&o.output, ".html");
            let failed = o.status == Status::Failed;
            LibraryRow {
                material: o.material.clone(),
                output: o.output.display().to_string(),
                report: (!failed && html.is_file()).then(|| report::link(&html, from)),
                status: format!("{:?}", o.status).to_lowercase(),
                bppc: o.record.bppc,
                psnr: o.record.psnr_db,
                ssim: o.record.ssim,
                seconds: o.record.seconds,
            }
        })
        .collect();
    let mut folders: Vec<&Path> = outcomes.iter().map(|o| o.input.as_path()).collect();
    folders.sort_unstable();
    folders.dedup();
    let mut plots = Vec::new();
    for folder in folders {
        let mut points: Vec<PlotPoint> = outcomes
            .iter()
            .filter(|o| o.input == folder && o.status != Status::Failed)
            .map(|o| PlotPoint::labelled("nmat", &o.output, o.record.bppc, o.record.psnr_db))
            .collect();
        let theirs = report::anchors_of(anchors, &report::material_name(folder));
        if points.is_empty() || points.len() + theirs.len() < 2 {
            continue;
        }
        points.extend(theirs);
        plots.push((format!("Rate and quality: {}", folder.display()), points));
    }
    report::library_page(&manifest.display().to_string(), &rows, &plots)
}

/// The file next to `output` with `suffix` appended to its name.
fn beside(output: &Path, suffix: &str) -> PathBuf {
    let mut name = output.file_name().map(|n| n.to_os_string()).unwrap_or_default();
    name.push(suffix);
    output.with_file_name(name)
}

fn build_one(job: &Job, exe: &Path, version: &str, threads: usize, force: bool) -> Outcome {
    let log = beside(&job.output, ".log");
    let mut outcome = Outcome {
        material: job.name.clone(),
        input: job.input.clone(),
        output: job.output.clone(),
        status: Status::Failed,
        record: Record::default(),
        error: String::new(),
        log: log.clone(),
    };
    let key = match manifest::build_key(job, version) {
        Ok(k) => k,
        Err(e) => {
            outcome.error = e;
            return outcome;
        }
    };
    let sidecar = beside(&job.output, ".build");
    if !force
        && job.output.is_file()
        && let Some(record) = std::fs::read(&sidecar)
            .ok()
            .and_then(|b| serde_json::from_slice::<Record>(&b).ok())
            .filter(|r| r.key == key)
    {
        outcome.status = Status::Cached;
        outcome.record = record;
        return outcome;
    }
    match encode(job, exe, threads, &log) {
        Ok(mut record) => {
            record.key = key;
            // The record goes last: an output without one (or with an old one) is rebuilt.
            let written = serde_json::to_vec_pretty(&record)
                .map_err(|e| e.to_string())
                .and_then(|b| output::write_atomic(&sidecar, &b).map_err(|e| e.to_string()));
            match written {
                Ok(()) => outcome.status = Status::Built,
                Err(e) => outcome.error = format!("{}: {e}", sidecar.display()),
            }
            outcome.record = record;
        }
        Err(e) => outcome.error = e,
    }
    outcome
}

/// `OUTPUT.html`: `nmat eval --report` of the output against its folder (made again only when
/// the output is newer than it); the eval's console goes to `OUTPUT.report.log`.
fn report(job: &Job, exe: &Path) -> std::result::Result<(), String> {
    let html = beside(&job.output, ".html");
    let modified = |p: &Path| std::fs::metadata(p).and_then(|m| m.modified()).ok();
    if modified(&html).is_some_and(|h| modified(&job.output).is_some_and(|o| h >= o)) {
        return Ok(());
    }
    let log = beside(&job.output, ".report.log");
    let file = std::fs::File::create(&log).map_err(|e| format!("{}: {e}", log.display()))?;
    let err = file.try_clone().map_err(|e| format!("{}: {e}", log.display()))?;
    let status = Command::new(exe)
        .arg("eval")
        .arg(&job.output)
        .arg("--ref")
        .arg(&job.input)
        .arg("--report")
        .arg(&html)
        .stdin(Stdio::null())
        .stdout(file)
        .stderr(err)
        .status()
        .map_err(|e| format!("{}: {e}", exe.display()))?;
    if !status.success() {
        return Err(format!("nmat eval --report exited with {status} (log {})", log.display()));
    }
    Ok(())
}

/// Runs `nmat encode` for `job` with its output into `log`; the quality it reports.
fn encode(
    job: &Job,
    exe: &Path,
    threads: usize,
    log: &Path,
) -> std::result::Result<Record, String> {
    if let Some(dir) = job.output.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    }
    let file = std::fs::File::create(log).map_err(|e| format!("{}: {e}", log.display()))?;
    let err = file.try_clone().map_err(|e| format!("{}: {e}", log.display()))?;
    let start = Instant::now();
    let status = Command::new(exe)
        .arg("encode")
        .args(&job.args)
        .args(["--threads", &threads.to_string()])
        .stdin(Stdio::null())
        .stdout(file)
        .stderr(err)
        .status()
        .map_err(|e| format!("{}: {e}", exe.display()))?;
    let text = std::fs::read_to_string(log).unwrap_or_default();
    if !status.success() {
        let tail: Vec<&str> = text.lines().rev().take(3).collect();
        let why = tail.into_iter().rev().collect::<Vec<_>>().join(" / ");
        return Err(format!("nmat encode exited with {status}: {why}"));
    }
    let mut record = parse_report(&text).ok_or("nmat encode printed no quality report")?;
    record.seconds = start.elapsed().as_secs_f64();
    Ok(record)
}

/// The quality table `nmat encode` prints: per-map lines (name, chain dB, one dB per mip), then
/// `overall: PSNR … dB …, SSIM … at mip 0, … bits per pixel per channel`.
fn parse_report(text: &str) -> Option<Record> {
    let lines: Vec<&str> = text.lines().collect();
    let overall = lines.iter().position(|l| l.starts_with("overall: PSNR "))?;
    let header = lines[..overall].iter().rposition(|l| l.starts_with("map "))?;
    let maps = lines[header + 1..overall]
        .iter()
        .filter_map(|l| {
            let tokens: Vec<&str> = l.split_whitespace().collect();
            let numeric = tokens.iter().rev().take_while(|t| t.parse::<f64>().is_ok()).count();
            let name = tokens.get(..tokens.len().checked_sub(numeric)?)?.join(" ");
            let psnr_db = tokens.get(tokens.len() - numeric)?.parse().ok()?;
            Some(MapQuality { map: name, psnr_db })
        })
        .collect();
    let o = lines[overall];
    let number_after = |key: &str| -> Option<f64> {
        o.split(key).nth(1)?.split_whitespace().next()?.trim_end_matches(',').parse().ok()
    };
    let bppc = o.split(" bits per pixel").next()?.rsplit(", ").next()?.parse().ok()?;
    Some(Record {
        key: String::new(),
        bppc,
        psnr_db: number_after("PSNR ")?,
        ssim: number_after("SSIM ")?,
        maps,
        seconds: 0.0,
    })
}

fn line(o: &Outcome) -> String {
    match o.status {
        Status::Failed => format!("{}: FAILED: {} (log {})", o.material, o.error, o.log.display()),
        s => format!(
            "{}: {} {}, {:.2} dB at {:.4} BPPC{}",
            o.material,
            if s == Status::Built { "built" } else { "up to date" },
            o.output.display(),
            o.record.psnr_db,
            o.record.bppc,
            if s == Status::Built {
                format!(" in {:.1} s", o.record.seconds)
            } else {
                String::new()
            }
        ),
    }
}

/// The summary: JSON if `path` ends in `.json`, else CSV (one row per material, the maps'
/// PSNR as `name=dB` separated by `;`).
fn write_summary(path: &Path, outcomes: &[Outcome]) -> Result<()> {
    let bytes = if path.extension().is_some_and(|e| e == "json") {
        serde_json::to_vec_pretty(outcomes).map_err(|e| e.to_string())?
    } else {
        let mut s =
            String::from("material,input,output,status,seconds,bppc,psnr_db,ssim,maps,error\n");
        let quote = |v: &str| format!("\"{}\"", v.replace('"', "\"\""));
        for o in outcomes {
            let maps: Vec<String> =
                o.record.maps.iter().map(|m| format!("{}={}", m.map, m.psnr_db)).collect();
            s.push_str(&format!(
                "{},{},{},{},{:.1},{},{},{},{},{}\n",
                quote(&o.material),
                quote(&o.input.display().to_string()),
                quote(&o.output.display().to_string()),
                serde_json::to_value(o.status)
                    .ok()
                    .and_then(|v| v.as_str().map(String::from))
                    .unwrap_or_default(),
                o.record.seconds,
                o.record.bppc,
                o.record.psnr_db,
                o.record.ssim,
                quote(&maps.join(";")),
                quote(&o.error)
            ));
        }
        s.into_bytes()
    };
    output::write_atomic(path, &bytes)?;
    Ok(())
}

/// Writes a build file with one edge per job: `nmat encode` (this binary, by absolute path)
/// with the job's arguments, depending on every file of its input folder, after creating the
/// output's folder. Paths are made absolute, so the file runs from any directory of a machine
/// that sees the same files (a shared file system).
fn emit(kind: EmitArg, path: &Path, manifest: &Path, jobs: &[Job]) -> Result<()> {
    let exe = std::env::current_exe().map_err(|e| format!("this program's path: {e}"))?;
    output::check_output(path, &[manifest.to_path_buf()])?;
    let absolute = |p: &Path| -> Result<PathBuf> {
        Ok(std::path::absolute(p).map_err(|e| format!("{}: {e}", p.display()))?)
    };
    let mut edges = Vec::new();
    for job in jobs {
        let mut inputs: Vec<PathBuf> = std::fs::read_dir(&job.input)
            .map_err(|e| format!("{}: {e}", job.input.display()))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.is_file())
            .map(|p| absolute(&p))
            .collect::<Result<_>>()?;
        inputs.sort();
        let out = absolute(&job.output)?;
        let mut args = job.args.clone();
        // The input folder and the output are the first and third arguments.
        args[0] = absolute(&job.input)?.display().to_string();
        args[2] = out.display().to_string();
        let dir = out.parent().map(|d| d.display().to_string()).unwrap_or_default();
        let words: Vec<String> = std::iter::once(exe.display().to_string())
            .chain(std::iter::once("encode".to_string()))
            .chain(args)
            .map(|w| shell_quote(&w))
            .collect();
        let command = format!("mkdir -p {} && {}", shell_quote(&dir), words.join(" "));
        edges.push((out, inputs, command));
    }
    let text = match kind {
        EmitArg::Ninja => ninja(manifest, &edges)?,
        EmitArg::Make => make(manifest, &edges)?,
    };
    output::write_atomic(path, text.as_bytes())?;
    println!("wrote {} ({} materials)", path.display(), edges.len());
    Ok(())
}

type Edge = (PathBuf, Vec<PathBuf>, String);

fn shell_quote(word: &str) -> String {
    format!("'{}'", word.replace('\'', "'\\''"))
}

fn ninja(manifest: &Path, edges: &[Edge]) -> Result<String> {
    // In a build line `$`, space and `:` are escaped with `$`; in a variable only `$` is.
    let path = |p: &Path| -> Result<String> {
        let s = p.display().to_string();
        if s.contains('\n') {
            return Err(format!("{s}: a path with a line break cannot go into a Ninja file").into());
        }
        Ok(s.replace('$', "$$").replace(' ', "$ ").replace(':', "$:"))
    };
    let mut s = format!(
        "# Written by `nmat build {} --emit ninja`: one edge per material.\n\
         rule encode\n  command = $command\n  description = nmat encode $out\n\n",
        manifest.display()
    );
    for (out, inputs, command) in edges {
        let deps: Vec<String> = inputs.iter().map(|p| path(p)).collect::<Result<_>>()?;
        s.push_str(&format!("build {}: encode {}\n", path(out)?, deps.join(" ")));
        s.push_str(&format!("  command = {}\n", command.replace('$', "$$")));
    }
    Ok(s)
}

fn make(manifest: &Path, edges: &[Edge]) -> Result<String> {
    // Make cannot name a file with a space, a colon, `#`, `%` or `$` in a rule.
    let path = |p: &Path| -> Result<String> {
        let s = p.display().to_string();
        if s.contains([' ', '\t', ':', '#', '%', '$', '\n', '\\']) {
            return Err(format!(
                "{s}: Make cannot name this file in a rule (a space, ':', '#', '%' or '$'); \
                 use --emit ninja"
            )
            .into());
        }
        Ok(s)
    };
    let outs: Vec<String> = edges.iter().map(|(o, _, _)| path(o)).collect::<Result<_>>()?;
    let mut s = format!(
        "# Written by `nmat build {} --emit make`: one rule per material.\n\
         .PHONY: all\nall: {}\n\n",
        manifest.display(),
        outs.join(" ")
    );
    for ((_, inputs, command), out) in edges.iter().zip(&outs) {
        let deps: Vec<String> = inputs.iter().map(|p| path(p)).collect::<Result<_>>()?;
        s.push_str(&format!("{out}: {}\n\t{}\n\n", deps.join(" "), command.replace('$', "$$")));
    }
    Ok(s)
}
