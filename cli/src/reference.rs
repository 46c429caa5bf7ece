//! `--ref`: the source maps `nmat eval` and `nmat bench` compare a material with, matched to
//! its channels by role.

use crate::common::Result;
use nmat_cli::output;
use nmat_core::Material;
use nmat_encode::metrics::ChainQuality;
use nmat_encode::texset::TextureSet;
use nmat_encode::texset::{self, LoadOptions, Role};
use std::path::{Path, PathBuf};

/// Loads the reference maps of `m` from `dir`: the files its SOURCE_MAPS section names if all are
/// there, else the images of `dir` whose role (told from the file name) is one of the material's.
/// The maps' channels must then match the material's by role and component, in order — else the
/// PSNR would compare, say, a roughness channel with a metallic map: refused, or with `force`
/// compared all the same after a warning.
pub fn load_reference(
    m: &Material<'_>,
    dir: &Path,
    force: bool,
    max_memory: u64,
) -> Result<TextureSet> {
    let roles: Vec<(Role, PathBuf)> = match output::source_maps(m) {
        Some(maps) if maps.iter().all(|s| dir.join(&s.file_name).is_file()) => {
            maps.iter().map(|s| (s.role, dir.join(&s.file_name))).collect()
        }
        _ => {
            let found = texset::assign_roles(&texset::collect_inputs(&[dir.to_path_buf()])?, &[])?;
            let mut ours: Vec<Role> =
                m.channels().iter().filter_map(|c| Role::from_semantic(c.semantic)).collect();
            ours.dedup();
            let missing: Vec<&str> = ours
                .iter()
                .filter(|r| !found.iter().any(|(f, _)| f == *r))
                .map(|r| r.name())
                .collect();
            if !missing.is_empty() && !force {
                let there: Vec<String> =
                    found.iter().map(|(r, p)| format!("{} {}", r.name(), p.display())).collect();
                return Err(format!(
                    "{}: no {} map among the reference maps ({}), so the material's channels \
                     would be compared with other maps. Point --ref at the maps this material \
                     was encoded from, or pass --force to compare anyway",
                    dir.display(),
                    missing.join(", no "),
                    there.join(", ")
                )
                .into());
            }
            if force {
                found
            } else {
                found.into_iter().filter(|(r, _)| ours.contains(r)).collect()
            }
        }
    };
    let set = texset::load(&roles, &LoadOptions { max_memory, ..LoadOptions::default() })?;
    if set.channel_count() != m.channel_count()
        || (set.width, set.height) != (m.width(), m.height())
    {
        return Err(format!(
            "{}: the reference maps give {}×{} with {} channels, the material is {}×{} with {}",
            dir.display(),
            set.width,
            set.height,
            set.channel_count(),
            m.width(),
            m.height(),
            m.channel_count()
        )
        .into());
    }
    let mismatches: Vec<String> = m
        .channels()
        .iter()
        .zip(&set.channels)
        .enumerate()
        .filter(|(_, (ours, theirs))| {
            (ours.semantic, ours.component) != (theirs.role.semantic(), theirs.component)
        })
        .map(|(i, (ours, theirs))| {
            let map = set
                .maps
                .iter()
                .find(|s| (s.first_channel..s.first_channel + s.channel_count).contains(&i));
            format!(
                "channel {i} is {} in the material but {} ({}) in the reference maps",
                nmat_encode::names::for_terminal(ours.name),
                theirs.name,
                map.map_or("?", |s| s.file_name.as_str())
            )
        })
        .collect();
    if let Some(first) = mismatches.first() {
        let what = format!(
            "{}: the reference maps do not match the material's channels: {first}{}",
            dir.display(),
            if mismatches.len() > 1 {
                format!(" (and {} more)", mismatches.len() - 1)
            } else {
                String::new()
            }
        );
        if !force {
            return Err(format!(
                "{what}; the numbers would compare different maps. Point --ref at the maps this \
                 material was encoded from, or pass --force to compare anyway"
            )
            .into());
        }
        eprintln!("warning: {what}; compared anyway (--force): the numbers below mix maps");
    }
    Ok(set)
}

/// Warns when the reference maps equal the material's own decode at mip 0: `--ref` then points
/// at decoded maps, not at the sources, and the PSNR says nothing about the codec.
pub fn warn_if_decoded(q: &ChainQuality, reference: &Path) {
    if q.mse.first().is_some_and(|mip0| mip0.iter().all(|&e| e == 0.0)) {
        eprintln!(
            "warning: the maps in {} are identical to this material's own decode at mip 0 — \
             they look like decoded maps, not the source maps it was encoded from, so the \
             numbers below do not measure the codec",
            reference.display()
        );
    }
}
