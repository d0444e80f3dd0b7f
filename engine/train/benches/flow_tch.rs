//! One full policy action at the pouring size (d = 7, context 6, 10 coupling layers of
//! 2×64 hidden) — inverse, latent step, forward, and the Jacobian-vector product of the
//! desired velocity — in the pure-Rust policy and in tch eager mode (f64, one thread, the
//! JVP by the double-backward trick), measured side by side in one run. The engine's
//! target is < 20 µs per action.
//!
//! `cargo bench -p ciflow-train --bench flow_tch`

use std::hint::black_box;
use std::time::Instant;

use ciflow_engine::flow::{CheckpointConfig, CouplingKind, FlowConfig, LatentKind, Policy};
use ciflow_train::latent::LatentInit;
use ciflow_train::policy::FlowModel;
use ciflow_train::trainer::{double_var_store, save_checkpoint};
use tch::{Kind, Tensor};

const Y: [f64; 7] = [0.1, -0.3, 0.2, -1.5, 0.05, 1.2, 0.4];
const CONTEXT: [f64; 6] = [0.5, 0.2, 0.3, 0.0, 0.1, -0.2];

/// Median over `rounds` of the mean time per call of `iterations` calls, in µs.
fn time_us(rounds: usize, iterations: usize, mut f: impl FnMut()) -> f64 {
    let mut samples: Vec<f64> = (0..rounds)
        .map(|_| {
            let start = Instant::now();
            for _ in 0..iterations {
                f();
            }
            start.elapsed().as_secs_f64() * 1e6 / iterations as f64
        })
        .collect();
    samples.sort_by(f64::total_cmp);
    samples[rounds / 2]
}

/// The tch action: `(mean next state, desired velocity J_f(z) A z)`.
fn tch_action(model: &FlowModel, y: &Tensor, c: &Tensor) -> (Tensor, Tensor) {
    let (z, _) = tch::no_grad(|| model.inverse(y, c));
    let next = tch::no_grad(|| model.forward(&model.latent().mean_step(&z), c).0);
    let a = model.latent().rate_matrix().expect("go-to latent").detach();
    let latent_velocity = z.matmul(&a.tr());
    let z = z.set_requires_grad(true);
    let (y_out, _) = model.forward(&z, c);
    let u = Tensor::zeros_like(&y_out).set_requires_grad(true);
    let vjp = Tensor::run_backward(&[(&y_out * &u).sum(Kind::Double)], &[&z], true, true);
    let jvp = Tensor::run_backward(
        &[(&vjp[0] * &latent_velocity).sum(Kind::Double)],
        &[&u],
        false,
        false,
    );
    (next, jvp[0].shallow_clone())
}

fn main() {
    tch::set_num_threads(1);
    let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    println!(
        "pouring-size action (d=7, m=6, 10 layers, 2×64 hidden), f64; load average {}",
        load.trim()
    );
    println!(
        "{:<8} {:>14} {:>14} {:>10} {:>14}",
        "coupling", "rust act µs", "tch eager µs", "tch/rust", "rel. |Δv|"
    );
    let dir = std::env::temp_dir().join(format!("ciflow-bench-{}", std::process::id()));
    for (name, coupling) in [
        ("affine", CouplingKind::AFFINE),
        (
            "spline",
            CouplingKind::Spline {
                bins: 8,
                tail_bound: 4.0,
            },
        ),
    ] {
        let config = FlowConfig::new(
            "pouring",
            7,
            6,
            LatentKind::GoTo,
            coupling,
            10,
            vec![64, 64],
        );
        let vs = double_var_store();
        let model = FlowModel::new(
            &vs.root(),
            &config,
            LatentInit {
                sigma: 0.1,
                omega: 0.0,
                speed: 1.0,
            },
        );
        tch::manual_seed(0);
        tch::no_grad(|| {
            for (_, mut v) in vs.variables() {
                v.copy_(&(Tensor::randn(v.size(), (Kind::Double, v.device())) * 0.1));
            }
        });
        save_checkpoint(&dir, &CheckpointConfig::Flow(config), &vs).expect("checkpoint");
        let policy = Policy::load(&dir, None).expect("policy");
        let mut ws = policy.workspace();
        let (mut next, mut velocity) = ([0.0; 7], [0.0; 7]);
        let rust = time_us(21, 2_000, || {
            policy
                .act(black_box(&Y), &CONTEXT, &mut ws, &mut next, &mut velocity)
                .unwrap();
            black_box(&velocity);
        });
        let y = Tensor::from_slice(&Y).reshape([1, 7]);
        let c = Tensor::from_slice(&CONTEXT).reshape([1, 6]);
        let eager = time_us(11, 50, || {
            let _ = black_box(tch_action(&model, &y, &c));
        });
        let (_, tch_velocity) = tch_action(&model, &y, &c);

        let tch_velocity = Vec::<f64>::try_from(tch_velocity.reshape([-1])).unwrap();
        let scale = velocity.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let difference = tch_velocity
            .iter()
            .zip(&velocity)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max)
            / scale;
        println!(
            "{name:<8} {rust:>14.1} {eager:>14.1} {:>10.1} {difference:>14.2e}",
            eager / rust
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}
