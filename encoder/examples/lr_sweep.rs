//! Learning-rate sweep on the procedural material: `cargo run --release -p nmat-encode --example
//! lr_sweep -- STEPS PROFILE LR_MLP,LR_LATENTS...`. Prints whole-chain PSNR per setting.

use nmat_encode::{EncodeOptions, Profile, TrainOptions, demo, encode};

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let steps: usize = args.first().and_then(|s| s.parse().ok()).unwrap_or(2000);
    let profile = Profile::by_name(args.get(1).map_or("ntc-0.5", |s| s)).expect("profile");
    let set = demo::bricks(256);
    for pair in args.iter().skip(2) {
        let (a, b) = pair.split_once(',').expect("LR_MLP,LR_LATENTS");
        let train = TrainOptions {
            steps,
            lr_mlp: a.parse().expect("the MLP learning rate, a number"),
            lr_latents: b.parse().expect("the latents' learning rate, a number"),
            ..TrainOptions::default()
        };
        let t = std::time::Instant::now();
        let out = encode(
            &set,
            &EncodeOptions { profile, train, ..EncodeOptions::default() },
            &mut |_| {},
        )
        .expect("the procedural material encodes");
        println!(
            "{pair}: {:.2} dB, {:.3} BPPC, {:.1} s",
            out.quality.psnr,
            out.quality.bppc,
            t.elapsed().as_secs_f64()
        );
    }
}
