//! The tch model and the pure-Rust policy are the same function: a checkpoint saved from
//! a `VarStore` loads in `Policy` and agrees to 1e-5 relative (f64 arithmetic on both
//! sides, the weights representable in `f32`, which is how the Rust MLPs store them); with
//! weights that are not, the rounding moves the Rust outputs by less than the 1e-4
//! relative the f32 storage is allowed. tch's log-determinant equals that of its own
//! autograd Jacobian.

use ciflow_engine::flow::{
    CheckpointConfig, ContextSet, ContractionConfig, CouplingKind, FlowConfig, JointRange,
    LatentKind, LocalConfig, Policy, SetEncoderConfig,
};
use ciflow_train::latent::LatentInit;
use ciflow_train::policy::FlowModel;
use ciflow_train::trainer::{double_var_store, save_checkpoint};
use std::sync::Mutex;

use tch::{Kind, Tensor};

/// libtorch's generator is global and the tests run on parallel threads: whoever seeds it
/// draws under this lock, so every test sees the draws its seeds promise.
static GENERATOR: Mutex<()> = Mutex::new(());

/// `draw` with libtorch's generator seeded with `seed`, alone.
fn seeded<T>(seed: i64, draw: impl FnOnce() -> T) -> T {
    let _alone = GENERATOR
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner());
    tch::manual_seed(seed);
    draw()
}

fn configs() -> Vec<FlowConfig> {
    let mut out = Vec::new();
    for coupling in [
        CouplingKind::AFFINE,
        CouplingKind::Affine {
            scale_bound: 2.0,
            taper_radius: Some(1.5),
        },
        CouplingKind::Spline {
            bins: 6,
            tail_bound: 2.5,
        },
    ] {
        for latent in [
            LatentKind::GoTo,
            LatentKind::SaturatedGoTo,
            LatentKind::LimitCycle,
        ] {
            out.push(normalised(latent, coupling.clone()));
        }
        out.push(goal_config(coupling.clone()));
        out.push(with_obstacle_set(coupling.clone(), vec![0, 3]));
        out.push(contracted(with_obstacle_set(coupling.clone(), vec![5, 6])));
        // The default set encoder: the pooled summary alone, no local features.
        let mut summary_only = with_obstacle_set(coupling.clone(), vec![0, 3]);
        if let Some(encoder) = &mut summary_only.set_encoder {
            encoder.local = None;
        }
        out.push(summary_only);
        // A robot's joint range last, with and without the target in the context (ranges
        // wide enough that the N(0, 2²) test states are inside).
        let mut ranged = normalised(LatentKind::GoTo, coupling.clone());
        let mut ranged_goal = goal_config(coupling.clone());
        for config in [&mut ranged, &mut ranged_goal] {
            let d = config.state_dim;
            config.joint_range = Some(JointRange {
                position_min: (0..d).map(|i| -7.0 - 0.5 * i as f64).collect(),
                position_max: (0..d).map(|i| 8.5 - i as f64).collect(),
                speed_max: vec![1.0; d],
                acceleration_max: vec![1.0; d],
            });
        }
        out.push(ranged);
        out.push(ranged_goal);
    }
    out
}

/// A 3-D flow with a 2-D context and non-trivial normalisation.
fn normalised(latent: LatentKind, coupling: CouplingKind) -> FlowConfig {
    let mut c = FlowConfig::new("parity", 3, 2, latent, coupling, 3, vec![12, 12]);
    c.normalisation.state_mean = vec![0.2, -0.4, 1.0];
    c.normalisation.state_std = vec![0.7, 1.8, 0.4];
    c.normalisation.context_mean = vec![0.5, 0.1];
    c.normalisation.context_std = vec![2.0, 0.3];
    c
}

/// A go-to flow in the plane whose target is the context's entries 2 and 1.
fn goal_config(coupling: CouplingKind) -> FlowConfig {
    let mut goal = FlowConfig::new("parity", 2, 3, LatentKind::GoTo, coupling, 3, vec![12]);
    goal.goal_context_indices = Some(vec![2, 1]);
    goal
}

/// A go-to flow whose context `[a, o₁, o₂, o₃]` holds an unordered set of three 2-D
/// elements, its goal `c[goal]` read from the raw context (indices inside the set too).
fn with_obstacle_set(coupling: CouplingKind, goal: Vec<usize>) -> FlowConfig {
    let mut config = FlowConfig::new("parity", 2, 7, LatentKind::GoTo, coupling, 4, vec![12]);
    config.goal_context_indices = Some(goal);
    config.context_sets = vec![ContextSet {
        start: 1,
        count: 3,
        size: 2,
    }];
    config.set_encoder = Some(SetEncoderConfig {
        hidden: vec![8],
        width: 4,
        local: Some(LocalConfig {
            hidden: vec![6],
            width: 3,
        }),
    });
    // The slots of a set share their statistics.
    config.normalisation.context_mean = vec![0.1, -0.2, 0.3, -0.2, 0.3, -0.2, 0.3];
    config.normalisation.context_std = vec![1.5, 0.5, 2.0, 0.5, 2.0, 0.5, 2.0];
    config
}

/// `config` contracted about its set's elements (obstacle centres).
fn contracted(mut config: FlowConfig) -> FlowConfig {
    config.contractions = Some(ContractionConfig {
        centres: config.context_sets[0],
        layers: 2,
        exponent: 2,
        radius: 0.6,
    });
    config
}

/// Re-draws every variable `N(0, 0.7²)` so the maps are far from the identity init; in
/// name order, so a seed gives the same model every run (the store's map has none). With
/// `f32_values`, each is then rounded to the nearest `f32` (kept as `f64`).
fn randomise(vs: &tch::nn::VarStore, seed: i64, f32_values: bool) {
    let mut variables: Vec<(String, Tensor)> = vs.variables().into_iter().collect();
    variables.sort_by(|a, b| a.0.cmp(&b.0));
    seeded(seed, || {
        tch::no_grad(|| {
            for (_, mut v) in variables {
                let mut noise = Tensor::randn(v.size(), (Kind::Double, v.device())) * 0.7;
                if f32_values {
                    noise = noise.to_kind(Kind::Float).to_kind(Kind::Double);
                }
                v.copy_(&noise);
            }
        })
    });
}

fn rows(t: &Tensor) -> Vec<Vec<f64>> {
    let n = t.size()[0];
    (0..n)
        .map(|i| Vec::<f64>::try_from(t.get(i)).unwrap())
        .collect()
}

/// `|a − b| ≤ 1e-5 (1 + max(|a|, |b|))`.
fn relative_close(a: f64, b: f64, what: &str) {
    within(a, b, 1e-5, what);
}

/// Both finite and `|a − b| ≤ tolerance (1 + max(|a|, |b|))`: an infinity on either side
/// would pass the bound (∞ ≤ ∞), so it is refused first.
fn within(a: f64, b: f64, tolerance: f64, what: &str) {
    assert!(
        a.is_finite() && b.is_finite() && (a - b).abs() <= tolerance * (1.0 + a.abs().max(b.abs())),
        "{what}: {a} vs {b}"
    );
}

#[test]
fn saved_var_store_loads_in_the_pure_rust_policy_and_agrees() {
    agrees_with_tch(true, 1e-5);
}

#[test]
fn weights_rounded_to_f32_move_the_rust_outputs_by_less_than_1e_4() {
    agrees_with_tch(false, 1e-4);
}

/// Saves random models (their variables `f32` values or not), loads them in `Policy` and
/// compares every output with tch's to `tolerance` relative.
fn agrees_with_tch(f32_values: bool, tolerance: f64) {
    let relative_close = |a: f64, b: f64, what: &str| {
        within(
            a,
            b,
            tolerance,
            &format!("{what}, tch vs rust (f32 values: {f32_values})"),
        )
    };
    let dir =
        std::env::temp_dir().join(format!("ciflow-parity-{}-{f32_values}", std::process::id()));
    for (k, config) in configs().iter().enumerate() {
        let vs = double_var_store();
        let model = FlowModel::new(
            &vs.root(),
            config,
            LatentInit {
                sigma: 0.1,
                omega: 1.0,
                speed: 1.0,
            },
        );
        randomise(&vs, k as i64, f32_values);
        save_checkpoint(&dir, &CheckpointConfig::Flow(config.clone()), &vs).unwrap();
        let policy = Policy::load(&dir, Some("parity")).unwrap();
        let mut ws = policy.workspace();

        let (d, m, n) = (config.state_dim as i64, config.context_dim as i64, 16);
        let (y, y_next, c) = seeded(100 + k as i64, || {
            let y = Tensor::randn([n, d], (Kind::Double, tch::Device::Cpu)) * 2.0;
            let y_next = &y + Tensor::randn([n, d], (Kind::Double, tch::Device::Cpu)) * 0.1;
            (
                y,
                y_next,
                Tensor::randn([n, m], (Kind::Double, tch::Device::Cpu)),
            )
        });
        let (z, _) = model.inverse(&y, &c);
        let mean_next = model.mean_next(&y, &c);
        let one = Tensor::ones([n], tch::kind::INT64_CPU);
        let log_transition = model.log_transition(&y, &y_next, &c, &one, 1);
        // Spans of 1, 2 and 3 steps mixed in one batch, as the trainer draws them.
        let spans = Tensor::arange(n, tch::kind::INT64_CPU).remainder(3) + 1;
        let log_transition_k = model.log_transition(&y, &y_next, &c, &spans, 3);
        let log_initial = model.log_initial(&y, &c);
        let (ys, cs, ns) = (rows(&y), rows(&c), rows(&y_next));
        let (zs, means) = (rows(&z), rows(&mean_next));
        for i in 0..n as usize {
            let mut out = vec![0.0; d as usize];
            policy
                .latent_state(&ys[i], &cs[i], &mut ws, &mut out)
                .unwrap();
            for j in 0..d as usize {
                relative_close(zs[i][j], out[j], "f⁻¹");
            }
            policy.mean_next(&ys[i], &cs[i], &mut ws, &mut out).unwrap();
            for j in 0..d as usize {
                relative_close(means[i][j], out[j], "mean next state");
            }
            let at = |t: &Tensor| t.double_value(&[i as i64]);
            relative_close(
                at(&log_transition),
                policy
                    .log_transition(&ys[i], &ns[i], &cs[i], &mut ws)
                    .unwrap(),
                "log p",
            );
            let k = spans.int64_value(&[i as i64]) as usize;
            relative_close(
                at(&log_transition_k),
                policy
                    .log_transition_multi(&ys[i], &ns[i], &cs[i], k, &mut ws)
                    .unwrap(),
                "k-step log p",
            );
            relative_close(
                at(&log_initial),
                policy.log_initial(&ys[i], &cs[i], &mut ws).unwrap(),
                "log p(y0)",
            );
        }
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn log_determinant_equals_the_autograd_jacobian() {
    for (k, config) in configs().iter().enumerate() {
        let vs = double_var_store();
        let model = FlowModel::new(
            &vs.root(),
            config,
            LatentInit {
                sigma: 0.1,
                omega: 1.0,
                speed: 1.0,
            },
        );
        randomise(&vs, 50 + k as i64, true);
        let (d, m) = (config.state_dim as i64, config.context_dim as i64);
        for point in 0..5 {
            // Drawn as states and carried to the latent: at a random latent point the
            // joint-range map can be saturated, where autograd's `1 − tanh²` cancels (its
            // relative error ≈ ε / (1 − tanh²), 1e-4 at u = 15) or is exactly 0, and the
            // reference, not the model, would be wrong.
            let (y, c) = seeded(200 + point, || {
                let y = Tensor::randn([1, d], (Kind::Double, tch::Device::Cpu)) * 2.0;
                (y, Tensor::randn([1, m], (Kind::Double, tch::Device::Cpu)))
            });
            let z = model.inverse(&y, &c).0.detach().set_requires_grad(true);
            let (y, log_det) = model.forward(&z, &c);
            let jacobian = Tensor::stack(
                &(0..d)
                    .map(|i| {
                        let grad = Tensor::run_backward(&[y.select(1, i)], &[&z], true, false);
                        grad[0].squeeze_dim(0)
                    })
                    .collect::<Vec<_>>(),
                0,
            );
            let expected = jacobian.det().abs().log().double_value(&[]);
            relative_close(
                log_det.double_value(&[0]),
                expected,
                "log|det J|, the model's vs autograd's",
            );
        }
    }
}

/// Permuting the set's elements changes neither model (with or without the radial
/// contractions), while moving one element does (the invariance is not the conditioners
/// ignoring the set).
#[test]
fn context_sets_make_both_models_invariant_to_permutations_of_the_set() {
    let dir = std::env::temp_dir().join(format!("ciflow-sets-{}", std::process::id()));
    let plain = with_obstacle_set(
        CouplingKind::Spline {
            bins: 6,
            tail_bound: 2.5,
        },
        vec![0, 0],
    );
    // The radial contractions sum over the centres: invariant too.
    for config in [plain.clone(), contracted(plain)] {
        let vs = double_var_store();
        let model = FlowModel::new(
            &vs.root(),
            &config,
            LatentInit {
                sigma: 0.1,
                omega: 1.0,
                speed: 1.0,
            },
        );
        randomise(&vs, 7, true);
        save_checkpoint(&dir, &CheckpointConfig::Flow(config.clone()), &vs).unwrap();
        let policy = Policy::load(&dir, Some("parity")).unwrap();
        let mut ws = policy.workspace();
        let y = [0.4, -0.7];
        let base = [0.3, 0.9, -0.4, 0.2, 1.1, -1.3, 0.5];
        let permuted = [0.3, 0.2, 1.1, -1.3, 0.5, 0.9, -0.4];
        let moved = [0.3, 0.9, -0.4, 0.2, 1.1, -1.3, 0.5 + 0.4];
        let latent = |c: &[f64; 7]| {
            let (z, _) = model.inverse(
                &Tensor::from_slice(&y).reshape([1, 2]),
                &Tensor::from_slice(c).reshape([1, 7]),
            );
            let tch = rows(&z).remove(0);
            let mut rust = vec![0.0; 2];
            let mut ws = policy.workspace();
            policy.latent_state(&y, c, &mut ws, &mut rust).unwrap();
            (tch, rust)
        };
        let ((tch, rust), (tch_permuted, rust_permuted)) = (latent(&base), latent(&permuted));
        for j in 0..2 {
            relative_close(tch[j], tch_permuted[j], "tch f⁻¹ under a permutation");
            relative_close(rust[j], rust_permuted[j], "rust f⁻¹ under a permutation");
            relative_close(tch[j], rust[j], "tch vs rust f⁻¹");
        }
        let (tch_moved, _) = latent(&moved);
        assert!((tch_moved[0] - tch[0]).abs() + (tch_moved[1] - tch[1]).abs() > 1e-6);
        let mut next = vec![0.0; 2];
        policy.mean_next(&y, &permuted, &mut ws, &mut next).unwrap();
        let mut next_base = vec![0.0; 2];
        policy
            .mean_next(&y, &base, &mut ws, &mut next_base)
            .unwrap();
        for j in 0..2 {
            relative_close(next[j], next_base[j], "mean next state under a permutation");
        }
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
