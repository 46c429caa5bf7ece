//! `nmat build`'s manifest: a TOML file listing materials (a folder, or the folders a pattern
//! matches) with their encode options and outputs, expanded into one `nmat encode` command line
//! per material, checked as a whole before any work starts (docs/ENCODING.md, "Building a
//! library").
//!
//! ```toml
//! [defaults]
//! profile = "ntc-0.5"
//! [[material]]
//! input = "textures/*"            # every folder here is one material
//! output = "out/{name}.nmat"
//! ```

use serde::Deserialize;
use std::collections::BTreeMap;
use std::path::{Component, Path, PathBuf};

/// The most materials one manifest may expand to (a pattern over a huge folder is refused
/// before anything is read further).
pub const MAX_MATERIALS: usize = 100_000;

/// Encode options of an entry or of `[defaults]`, as `nmat encode` takes them (the flag of each
/// is its name with `_` as `-`).
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Options {
    pub codec: Option<String>,
    pub profile: Option<String>,
    pub bppc: Option<f64>,
    pub quality: Option<u8>,
    pub target_psnr: Option<f64>,
    pub steps: Option<usize>,
    pub effort: Option<String>,
    pub seed: Option<u64>,
    pub address: Option<String>,
    pub subsampling: Option<String>,
    pub resize: Option<bool>,
    pub fixed_rate: Option<bool>,
    pub memory_factor: Option<f64>,
    pub output_margin: Option<f32>,
    pub layout: Option<String>,
    pub hi_bilinear: Option<String>,
    pub polish_sweeps: Option<u8>,
}

impl Options {
    /// `self` where set, else `defaults` — but a JPEG entry does not inherit the neural
    /// codec's options (`profile`, `target_psnr`, `steps`, `effort`, `seed`, `memory_factor`,
    /// `output_margin`, `layout`, `hi_bilinear`, `polish_sweeps`) from the defaults, nor a neural one JPEG's
    /// (`quality`, `subsampling`): `[defaults]` may hold both.
    fn over(&self, defaults: &Options) -> Options {
        let codec = self.codec.clone().or_else(|| defaults.codec.clone());
        let jpeg = codec.as_deref() == Some("jpeg");
        let defaults = Options {
            profile: defaults.profile.clone().filter(|_| !jpeg),
            target_psnr: defaults.target_psnr.filter(|_| !jpeg),
            steps: defaults.steps.filter(|_| !jpeg),
            effort: defaults.effort.clone().filter(|_| !jpeg),
            seed: defaults.seed.filter(|_| !jpeg),
            memory_factor: defaults.memory_factor.filter(|_| !jpeg),
            output_margin: defaults.output_margin.filter(|_| !jpeg),
            layout: defaults.layout.clone().filter(|_| !jpeg),
            hi_bilinear: defaults.hi_bilinear.clone().filter(|_| !jpeg),
            polish_sweeps: defaults.polish_sweeps.filter(|_| !jpeg),
            quality: defaults.quality.filter(|_| jpeg),
            subsampling: defaults.subsampling.clone().filter(|_| jpeg),
            ..defaults.clone()
        };
        let defaults = &defaults;
        Options {
            codec,
            profile: self.profile.clone().or_else(|| defaults.profile.clone()),
            bppc: self.bppc.or(defaults.bppc),
            quality: self.quality.or(defaults.quality),
            target_psnr: self.target_psnr.or(defaults.target_psnr),
            steps: self.steps.or(defaults.steps),
            effort: self.effort.clone().or_else(|| defaults.effort.clone()),
            seed: self.seed.or(defaults.seed),
            address: self.address.clone().or_else(|| defaults.address.clone()),
            subsampling: self.subsampling.clone().or_else(|| defaults.subsampling.clone()),
            resize: self.resize.or(defaults.resize),
            fixed_rate: self.fixed_rate.or(defaults.fixed_rate),
            memory_factor: self.memory_factor.or(defaults.memory_factor),
            output_margin: self.output_margin.or(defaults.output_margin),
            layout: self.layout.clone().or_else(|| defaults.layout.clone()),
            hi_bilinear: self.hi_bilinear.clone().or_else(|| defaults.hi_bilinear.clone()),
            polish_sweeps: self.polish_sweeps.or(defaults.polish_sweeps),
        }
    }

    /// The `nmat encode` flags these options stand for, in a fixed order.
    fn flags(&self) -> Vec<String> {
        let mut f = Vec::new();
        let mut push = |flag: &str, value: Option<String>| {
            if let Some(v) = value {
                f.push(format!("--{flag}"));
                f.push(v);
            }
        };
        push("codec", self.codec.clone());
        push("profile", self.profile.clone());
        push("bppc", self.bppc.map(|v| v.to_string()));
        push("quality", self.quality.map(|v| v.to_string()));
        push("target-psnr", self.target_psnr.map(|v| v.to_string()));
        push("steps", self.steps.map(|v| v.to_string()));
        push("effort", self.effort.clone());
        push("seed", self.seed.map(|v| v.to_string()));
        push("address", self.address.clone());
        push("subsampling", self.subsampling.clone());
        push("memory-factor", self.memory_factor.map(|v| v.to_string()));
        push("output-margin", self.output_margin.map(|v| v.to_string()));
        push("layout", self.layout.clone());
        push("hi-bilinear", self.hi_bilinear.clone());
        push("polish-sweeps", self.polish_sweeps.map(|v| v.to_string()));
        if self.resize == Some(true) {
            f.push("--resize".into());
        }
        if self.fixed_rate == Some(true) {
            f.push("--fixed-rate".into());
        }
        f
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Entry {
    input: String,
    output: String,
    #[serde(flatten)]
    options: Options,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    #[serde(default)]
    defaults: Options,
    #[serde(default)]
    material: Vec<Entry>,
}

/// One material to build: its folder, its output and the `nmat encode` arguments that build it
/// (after `encode`, without the thread count, which does not change the bytes).
#[derive(Clone, Debug, PartialEq)]
pub struct Job {
    /// The folder's name, `{name}` in output templates.
    pub name: String,
    pub input: PathBuf,
    pub output: PathBuf,
    pub args: Vec<String>,
}

/// Reads and expands the manifest at `path`; paths in it are relative to its folder. Every
/// problem is an error naming the entry and what is wrong, before any material is encoded.
pub fn load(path: &Path) -> Result<Vec<Job>, String> {
    let shown = path.display();
    let text = std::fs::read_to_string(path).map_err(|e| format!("{shown}: {e}"))?;
    let base = path.parent().unwrap_or(Path::new("."));
    expand(&text, base).map_err(|e| format!("{shown}: {e}"))
}

/// [`load`] of manifest `text` whose relative paths start at `base`.
pub fn expand(text: &str, base: &Path) -> Result<Vec<Job>, String> {
    let file: File = toml::from_str(text).map_err(|e| e.to_string())?;
    if file.material.is_empty() {
        return Err("no [[material]] entry".into());
    }
    let mut jobs = Vec::new();
    for (i, entry) in file.material.iter().enumerate() {
        let what = format!("[[material]] {} (input = {:?})", i + 1, entry.input);
        if !entry.output.contains("{name}") && entry.input.contains(['*', '?']) {
            return Err(format!(
                "{what}: output {:?} has no {{name}}: every folder the pattern matches would \
                 write the same file",
                entry.output
            ));
        }
        let folders = folders(base, &entry.input).map_err(|e| format!("{what}: {e}"))?;
        let options = entry.options.over(&file.defaults);
        for folder in folders {
            let name = folder.file_name().map_or(String::new(), |n| n.to_string_lossy().into());
            let output = base.join(entry.output.replace("{name}", &name));
            let mut args = vec![folder.display().to_string(), "-o".into()];
            args.push(output.display().to_string());
            args.extend(options.flags());
            jobs.push(Job { name, input: folder, output, args });
            if jobs.len() > MAX_MATERIALS {
                return Err(format!("{what}: more than {MAX_MATERIALS} materials"));
            }
        }
    }
    check_outputs(&jobs)?;
    jobs.sort_by(|a, b| a.output.cmp(&b.output));
    Ok(jobs)
}

/// The folders `pattern` names: one folder, or with `*` / `?` in its last component every
/// folder there whose name matches (sorted; hidden ones only if the pattern starts with `.`).
fn folders(base: &Path, pattern: &str) -> Result<Vec<PathBuf>, String> {
    let path = base.join(pattern);
    let last = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let parent = path.parent().unwrap_or(Path::new("."));
    if parent.to_string_lossy().contains(['*', '?']) {
        return Err("patterns may use * and ? in the last component only".into());
    }
    if !last.contains(['*', '?']) {
        if !path.is_dir() {
            return Err(format!("{} is not a folder", path.display()));
        }
        return Ok(vec![path]);
    }
    let entries = std::fs::read_dir(parent).map_err(|e| format!("{}: {e}", parent.display()))?;
    let mut found = Vec::new();
    for entry in entries {
        let entry = entry.map_err(|e| format!("{}: {e}", parent.display()))?;
        let name = entry.file_name().to_string_lossy().into_owned();
        if (name.starts_with('.') && !last.starts_with('.')) || !matches(&last, &name) {
            continue;
        }
        // Folders only, not followed through links (a link back up would make a cycle).
        if entry.file_type().is_ok_and(|t| t.is_dir()) {
            found.push(entry.path());
            if found.len() > MAX_MATERIALS {
                return Err(format!("matches more than {MAX_MATERIALS} folders"));
            }
        }
    }
    if found.is_empty() {
        return Err(format!("matches no folder in {}", parent.display()));
    }
    found.sort();
    Ok(found)
}

/// `*` any run of characters, `?` one character, others themselves.
fn matches(pattern: &str, name: &str) -> bool {
    let (p, n): (Vec<char>, Vec<char>) = (pattern.chars().collect(), name.chars().collect());
    // Classic two-pointer wildcard match with backtracking to the last `*`.
    let (mut i, mut j, mut star, mut mark) = (0, 0, None, 0);
    while j < n.len() {
        if i < p.len() && (p[i] == '?' || p[i] == n[j]) {
            i += 1;
            j += 1;
        } else if i < p.len() && p[i] == '*' {
            star = Some(i);
            mark = j;
            i += 1;
        } else if let Some(s) = star {
            i = s + 1;
            mark += 1;
            j = mark;
        } else {
            return false;
        }
    }
    p[i..].iter().all(|&c| c == '*')
}

/// No two materials write one file, and no output lies inside an input folder (the next build
/// would read it as a map).
fn check_outputs(jobs: &[Job]) -> Result<(), String> {
    let mut seen: BTreeMap<PathBuf, &Job> = BTreeMap::new();
    for job in jobs {
        let key = normal(&job.output);
        if let Some(first) = seen.insert(key.clone(), job) {
            return Err(format!(
                "{} and {} both write {}",
                first.input.display(),
                job.input.display(),
                job.output.display()
            ));
        }
    }
    for job in jobs {
        let out = normal(&job.output);
        if let Some(input) = jobs.iter().find(|j| out.starts_with(normal(&j.input))) {
            return Err(format!(
                "output {} is inside the input folder {}: a later build would read it as a map",
                job.output.display(),
                input.input.display()
            ));
        }
    }
    Ok(())
}

/// `path` without `.` components and with `..` applied where it can be (no file system access).
fn normal(path: &Path) -> PathBuf {
    let mut out = PathBuf::new();
    for c in path.components() {
        match c {
            Component::CurDir => {}
            Component::ParentDir if out.file_name().is_some() => {
                out.pop();
            }
            other => out.push(other),
        }
    }
    out
}

/// Shard `k` of `n` (1-based): whether `job` belongs to it. By a hash of the output path, so
/// every machine splits a manifest the same way and adding a material moves no other.
pub fn in_shard(job: &Job, k: usize, n: usize) -> bool {
    (fnv1a(job.output.to_string_lossy().as_bytes()) % n as u64) as usize == k - 1
}

/// `K/N` with 1 ≤ K ≤ N.
pub fn parse_shard(s: &str) -> Result<(usize, usize), String> {
    let bad = || format!("--shard {s}: give K/N with 1 ≤ K ≤ N, e.g. 2/8");
    let (k, n) = s.split_once('/').ok_or_else(bad)?;
    let (k, n): (usize, usize) = (k.parse().map_err(|_| bad())?, n.parse().map_err(|_| bad())?);
    if k == 0 || k > n {
        return Err(bad());
    }
    Ok((k, n))
}

/// 64-bit FNV-1a, for shard assignment and change detection (not security: the key of a build
/// decides whether an output is rebuilt, nobody gains from forging one).
pub fn fnv1a(bytes: &[u8]) -> u64 {
    bytes
        .iter()
        .fold(0xcbf2_9ce4_8422_2325, |h, &b| (h ^ u64::from(b)).wrapping_mul(0x100_0000_01b3))
}

/// What an output is built from: the encoder's version, the arguments, and every file of the
/// input folder (name and bytes, in name order); a different key means rebuild.
pub fn build_key(job: &Job, version: &str) -> Result<String, String> {
    let mut h = fnv1a(version.as_bytes());
    let mut mix = |bytes: &[u8]| {
        h = fnv1a(
            &[h.to_le_bytes().as_slice(), &(bytes.len() as u64).to_le_bytes(), bytes].concat(),
        )
    };
    for a in &job.args[1..] {
        mix(a.as_bytes());
    }
    let mut files: Vec<PathBuf> = std::fs::read_dir(&job.input)
        .map_err(|e| format!("{}: {e}", job.input.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file())
        .collect();
    files.sort();
    for f in files {
        mix(f.file_name().map_or(&[][..], |n| n.as_encoded_bytes()));
        mix(&std::fs::read(&f).map_err(|e| format!("{}: {e}", f.display()))?);
    }
    Ok(format!("{h:016x}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wildcards_match_like_a_shell() {
        for (p, n, want) in [
            ("*", "rock", true),
            ("r*k", "rock", true),
            ("r?ck", "rock", true),
            ("stk-*", "stk-ice", true),
            ("stk-*", "rock", false),
            ("*a*b", "xaxb", true),
            ("*a*b", "xaxbc", false),
            ("", "", true),
            ("?", "", false),
        ] {
            assert_eq!(matches(p, n), want, "{p} vs {n}");
        }
    }

    #[test]
    fn entries_inherit_only_their_codecs_defaults() {
        let dir = std::env::temp_dir().join(format!("nmat-manifest-{}", std::process::id()));
        std::fs::create_dir_all(dir.join("a")).unwrap();
        let jobs = expand(
            "[defaults]\nprofile = \"ntc-0.2\"\nquality = 70\nsteps = 9\nmemory_factor = 1.25\n\
             output_margin = 0.01\nlayout = \"bits-first\"\nhi_bilinear = \"off\"\npolish_sweeps = 1\n\
             [[material]]\ninput = \"a\"\noutput = \"n.nmat\"\n\
             [[material]]\ninput = \"a\"\noutput = \"t.nmat\"\nlayout = \"trial\"\n\
             [[material]]\ninput = \"a\"\noutput = \"j.nmat\"\ncodec = \"jpeg\"\n\
             [[material]]\ninput = \"a\"\noutput = \"k.nmat\"\ncodec = \"jpeg\"\nsteps = 3\n",
            &dir,
        )
        .unwrap();
        let args = |name: &str| {
            let job = jobs.iter().find(|j| j.output.ends_with(name)).unwrap();
            job.args[3..].join(" ")
        };
        assert_eq!(
            args("n.nmat"),
            "--profile ntc-0.2 --steps 9 --memory-factor 1.25 --output-margin 0.01 --layout bits-first \
             --hi-bilinear off --polish-sweeps 1"
        );
        assert_eq!(
            args("t.nmat"),
            "--profile ntc-0.2 --steps 9 --memory-factor 1.25 --output-margin 0.01 --layout trial \
             --hi-bilinear off --polish-sweeps 1"
        );
        assert_eq!(args("j.nmat"), "--codec jpeg --quality 70");
        // Set on the entry itself: passed on (and `nmat encode` names the conflict).
        assert_eq!(args("k.nmat"), "--codec jpeg --quality 70 --steps 3");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn shards_partition_the_jobs() {
        let jobs: Vec<Job> = (0..50)
            .map(|i| Job {
                name: i.to_string(),
                input: PathBuf::from(format!("in/{i}")),
                output: PathBuf::from(format!("out/{i}.nmat")),
                args: Vec::new(),
            })
            .collect();
        for n in 1..6 {
            for job in &jobs {
                assert_eq!((1..=n).filter(|&k| in_shard(job, k, n)).count(), 1);
            }
        }
        assert_eq!(parse_shard("2/8"), Ok((2, 8)));
        for bad in ["0/3", "4/3", "2", "a/b", "1/0"] {
            assert!(parse_shard(bad).is_err(), "{bad}");
        }
    }
}
