//! Renders frames of an expert episode to PNG files, to look at what `render` draws.
//!
//! `cargo run --release -p ciflow-envs --example render -- TASK OUT_DIR [SEED] [STEP...]`
//! writes `OUT_DIR/<task>-<step>.png` (480 × 480) at the given steps (default: the start,
//! a third, two thirds and the end of the episode).

use std::path::PathBuf;

use ciflow_envs::{ResetOptions, make};

const SIZE: u32 = 480;

fn write_png(path: &PathBuf, pixels: &[u8]) -> Result<(), Box<dyn std::error::Error>> {
    let file = std::io::BufWriter::new(std::fs::File::create(path)?);
    let mut encoder = png::Encoder::new(file, SIZE, SIZE);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    encoder.write_header()?.write_image_data(pixels)?;
    Ok(())
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [task, out, rest @ ..] = args.as_slice() else {
        return Err("usage: render TASK OUT_DIR [SEED] [STEP...]".into());
    };
    let seed: u64 = rest.first().map(|s| s.parse()).transpose()?.unwrap_or(0);
    let mut steps: Vec<u32> = rest
        .iter()
        .skip(1)
        .map(|s| s.parse())
        .collect::<Result<_, _>>()?;
    let mut env = make(task)?;
    if steps.is_empty() {
        let n = env.spec().max_episode_steps;
        steps = vec![0, n / 3, 2 * n / 3, n];
    }
    std::fs::create_dir_all(out)?;
    env.reset(Some(seed), &ResetOptions::default())?;
    let name = task.replace('/', "_");
    let mut step = 0;
    loop {
        if steps.contains(&step) {
            let path = PathBuf::from(out).join(format!("{name}-{step:04}.png"));
            write_png(&path, &env.render(SIZE, SIZE)?)?;
            println!("{}", path.display());
        }
        if step >= *steps.iter().max().unwrap() {
            return Ok(());
        }
        let result = env.step(&env.expert_action()?)?;
        step += 1;
        if result.terminated || result.truncated {
            let path = PathBuf::from(out).join(format!("{name}-{step:04}-end.png"));
            write_png(&path, &env.render(SIZE, SIZE)?)?;
            println!("{}", path.display());
            return Ok(());
        }
    }
}
