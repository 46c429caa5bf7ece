//! `nmat transcode`: a .nmat file → BC1/BC4/BC5/BC7 textures in KTX2 or DDS files, all or
//! nothing.

use crate::args::{ContainerArg, FormatArg, TranscodeArgs};
use crate::common::{Result, mib, parse, refuse_existing, threads, with_decode_progress};
use clap::ValueEnum;
use nmat_cli::input::read_nmat;
use nmat_cli::output;
use nmat_encode::names;
use nmat_encode::texset::Role;
use std::time::Instant;

pub fn run(args: TranscodeArgs) -> Result<()> {
    use nmat_cli::transcode::{self, Choice, Container};
    threads(args.threads)?;
    let mut choice = Choice { all: args.format.format(), by_semantic: Vec::new() };
    for text in &args.as_role {
        let (role, format) = text
            .split_once('=')
            .ok_or_else(|| format!("--as {text}: expected ROLE=FORMAT, e.g. albedo=bc7"))?;
        let role = Role::parse(role.trim()).ok_or_else(|| {
            let roles: Vec<&str> = Role::ALL.iter().map(|r| r.name()).collect();
            format!("--as {text}: unknown role {role:?}; choose one of {}", roles.join(", "))
        })?;
        let format = FormatArg::from_str(format.trim(), true)
            .ok()
            .and_then(FormatArg::format)
            .ok_or_else(|| format!("--as {text}: the format must be bc1, bc4, bc5 or bc7"))?;
        match choice.by_semantic.iter().find(|(s, _)| *s == role.semantic()) {
            Some(&(_, earlier)) if earlier != format => {
                return Err(format!(
                    "--as {text}: {} maps were already given {} by an earlier --as; give one \
                     format per role",
                    role.name(),
                    earlier.name()
                )
                .into());
            }
            Some(_) => {}
            None => choice.by_semantic.push((role.semantic(), format)),
        }
    }
    let container = match args.container {
        ContainerArg::Ktx2 => Container::Ktx2,
        ContainerArg::Dds => Container::Dds,
    };
    let bytes = read_nmat(&args.input)?;
    let m = parse(&bytes, &args.input)?;
    let plan = transcode::plan(&m, &choice);
    let names: Vec<String> = plan.iter().map(|n| transcode::file_name(n, container)).collect();
    if !args.force {
        refuse_existing(&args.output, &names)?;
    }
    let textures: Vec<_> = plan.iter().map(|n| n.texture).collect();
    let (need, allowed) = (transcode::memory(&m, &textures), args.memory.bytes());
    if need > allowed {
        return Err(format!(
            "{}: transcoding needs about {:.1} MiB, more than the {:.1} MiB allowed; nothing \
             was written. Raise the limit with --max-memory",
            args.input.display(),
            mib(need),
            mib(allowed)
        )
        .into());
    }
    let start = Instant::now();
    let decoder = nmat_core::Decoder::new(&m);
    let choices = args.kernel_choices.as_deref();
    let gpu = if args.gpu { Some(crate::gpu::transcoder(&m, choices)?) } else { None };
    // One decode of the chain for the GPU's textures, one for all the others on the CPU.
    let chain = output::cost_of_mips(&m, 0..m.mip_count());
    let on_gpu =
        plan.iter().filter(|n| gpu.is_some() && crate::gpu::encodes(n.texture.format)).count();
    let passes = (usize::from(on_gpu > 0) + usize::from(on_gpu < plan.len())) as u64;
    let cost = nmat_core::DecodeCost { texels: chain.texels * passes, macs: chain.macs * passes };
    let written = with_decode_progress("transcode", cost, |progress| {
        output::write_all_or_nothing(&args.output, |dir| {
            // The GPU's textures first (with --gpu), then all the others in one CPU pass.
            let images: Vec<Option<_>> = match &gpu {
                Some(levels_of) => levels_of(&textures, &mut *progress)?
                    .into_iter()
                    .zip(&textures)
                    .map(|(levels, t)| levels.map(|levels| transcode::image(&m, t, levels)))
                    .collect(),
                None => plan.iter().map(|_| None).collect(),
            };
            let on_cpu: Vec<_> = plan
                .iter()
                .zip(&images)
                .filter(|(_, i)| i.is_none())
                .map(|(n, _)| n.texture)
                .collect();
            let mut cpu_images = transcode::transcode(&m, &decoder, &on_cpu, progress)
                .map_err(|e| format!("{}: {e}", args.input.display()))?
                .into_iter();
            let mut files = Vec::new();
            for (image, name) in images.into_iter().zip(&names) {
                let image =
                    image.or_else(|| cpu_images.next()).ok_or("a texture was not transcoded")?;
                let path = dir.join(name);
                output::write_atomic(&path, &container.bytes(&image))?;
                files.push(path);
            }
            Ok(files)
        })
    })?;
    for ((named, path), name) in plan.iter().zip(&written).zip(&names) {
        let t = &named.texture;
        let channels: Vec<std::borrow::Cow<str>> = t
            .channel_list()
            .iter()
            .map(|&c| {
                m.channels()
                    .get(usize::from(c))
                    .map_or("?".into(), |ch| names::for_terminal(ch.name))
            })
            .collect();
        let size = std::fs::metadata(path).map_or(0, |md| md.len());
        println!(
            "wrote {name}  {}{}  {}  {size} bytes",
            t.format.name(),
            if t.srgb { " sRGB" } else { "" },
            channels.join(" ")
        );
    }
    println!(
        "transcoded {}×{} ({} mips) to {} textures in {:.2} s",
        m.width(),
        m.height(),
        m.mip_count(),
        written.len(),
        start.elapsed().as_secs_f64()
    );
    Ok(())
}
