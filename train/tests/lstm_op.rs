//! The fused LSTM op (`train::ppo::lstm_op`) against candle's own ops step by step: the same
//! outputs and the same gradients for every actor tensor, over sequences with episode resets in
//! the middle and a non-zero starting state (what the PPO update replays).
use candle_core::{DType, Device, Tensor};
use train::ppo::policy::{ActorArch, ActorCritic, Recurrence};

fn random(rng: &mut labkit::rng::Rng, n: usize, scale: f64) -> Vec<f32> {
    (0..n).map(|_| rng.range(-scale, scale) as f32).collect()
}

/// Actor means and the gradient of a fixed random projection of them, for one recurrence.
fn run(ac: &mut ActorCritic, how: Recurrence, inputs: &Inputs) -> (Vec<f32>, Vec<(String, Vec<f32>)>) {
    ac.recurrence = how;
    let dev = Device::Cpu;
    let (t, b, o, h) = (inputs.t, inputs.b, ac.obs_dim, ac.arch.lstm_hidden());
    let obs = Tensor::from_vec(inputs.obs.clone(), (t, b, o), &dev).unwrap();
    let h0 = Tensor::from_vec(inputs.h0.clone(), (b, h), &dev).unwrap();
    let c0 = Tensor::from_vec(inputs.c0.clone(), (b, h), &dev).unwrap();
    let masks = Tensor::from_vec(inputs.masks.clone(), (t, b, 1), &dev).unwrap();
    let mean = ac.actor_sequence(&obs, Some((&h0, &c0)), &masks).unwrap();
    let proj = Tensor::from_vec(inputs.proj.clone(), mean.shape(), &dev).unwrap();
    let loss = (&mean * &proj).unwrap().sum_all().unwrap();
    let grads = loss.backward().unwrap();
    let mut out = Vec::new();
    for (name, _) in ac.arch.shapes() {
        let var = ac.vars.data().lock().unwrap()[&name].clone();
        let g = grads
            .get(var.as_tensor())
            .unwrap_or_else(|| panic!("no gradient for {name}"));
        out.push((name, g.flatten_all().unwrap().to_vec1().unwrap()));
    }
    (mean.flatten_all().unwrap().to_vec1().unwrap(), out)
}

struct Inputs {
    t: usize,
    b: usize,
    obs: Vec<f32>,
    h0: Vec<f32>,
    c0: Vec<f32>,
    masks: Vec<f32>,
    proj: Vec<f32>,
}

fn max_rel(a: &[f32], b: &[f32]) -> f32 {
    let scale = b.iter().fold(0.0f32, |m, x| m.max(x.abs())).max(1e-6);
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0f32, f32::max) / scale
}

#[test]
fn fused_lstm_matches_candle_step_by_step_in_values_and_gradients() {
    let (obs_dim, act) = (51, 12);
    let mut ac = ActorCritic::with_arch(ActorArch::peer_lstm(obs_dim, act), 60, 0.5, 7).unwrap();
    let mut rng = labkit::rng::Rng(42);
    let (t, b, h) = (20, 5, ac.arch.lstm_hidden());
    let mut masks = vec![1.0f32; t * b];
    // Episode starts mid-sequence (the state is reset before those steps), one in the first row.
    for &(s, r) in &[(0, 1), (7, 0), (7, 3), (13, 2), (19, 4)] {
        masks[s * b + r] = 0.0;
    }
    let inputs = Inputs {
        t,
        b,
        obs: random(&mut rng, t * b * obs_dim, 2.0),
        h0: random(&mut rng, b * h, 0.8),
        c0: random(&mut rng, b * h, 1.5),
        masks,
        proj: random(&mut rng, t * b * act, 1.0),
    };
    let (mean_ref, grads_ref) = run(&mut ac, Recurrence::StepByStep, &inputs);
    let (mean, grads) = run(&mut ac, Recurrence::Fused, &inputs);
    let dm = max_rel(&mean, &mean_ref);
    eprintln!("means: max |Δ| / max |x| = {dm:.2e}");
    assert!(dm < 1e-5, "fused LSTM means differ: {dm}");
    assert!(
        mean_ref.iter().any(|x| x.abs() > 1e-2),
        "the actor's outputs are all near zero: the test compares nothing"
    );
    for ((name, g), (_, g_ref)) in grads.iter().zip(&grads_ref) {
        let d = max_rel(g, g_ref);
        eprintln!("{name}: max |Δ| / max |g| = {d:.2e}");
        assert!(d < 1e-4, "gradient of {name} differs: {d}");
        assert!(g_ref.iter().any(|x| *x != 0.0), "gradient of {name} is zero");
    }
}

#[test]
fn fused_lstm_refuses_inputs_of_the_wrong_shape() {
    let op = train::ppo::lstm_op::LstmSequence::new(3, 2, 4, vec![0.0; 8], vec![0.0; 8], vec![1.0; 6]).unwrap();
    let dev = Device::Cpu;
    let xproj = Tensor::zeros((3, 2, 15), DType::F32, &dev).unwrap();
    let w_hh = Tensor::zeros((16, 4), DType::F32, &dev).unwrap();
    let err = op.apply(&xproj, &w_hh).unwrap_err().to_string();
    assert!(err.contains("need [3, 2, 16]"), "{err}");
    assert!(
        train::ppo::lstm_op::LstmSequence::new(3, 2, 4, vec![0.0; 7], vec![0.0; 8], vec![1.0; 6]).is_err(),
        "a state of the wrong length must be refused"
    );
}

/// The fused ELU op (`train::ppo::elu_op`) against candle's own `elu`: values and gradient.
#[test]
fn fused_elu_matches_candle_s_elu() {
    let dev = Device::Cpu;
    let mut rng = labkit::rng::Rng(3);
    let mut x = random(&mut rng, 600, 4.0);
    x[0] = 0.0;
    x[1] = -0.0;
    let proj = Tensor::from_vec(random(&mut rng, 600, 1.0), (20, 30), &dev).unwrap();
    let grad_of = |fused: bool| {
        let v = candle_core::Var::from_tensor(&Tensor::from_vec(x.clone(), (20, 30), &dev).unwrap()).unwrap();
        let y = if fused {
            train::ppo::elu_op::Elu { alpha: 1.0 }.apply(v.as_tensor()).unwrap()
        } else {
            v.as_tensor().elu(1.0).unwrap()
        };
        let g = (&y * &proj).unwrap().sum_all().unwrap().backward().unwrap();
        let g: Vec<f32> = g.get(v.as_tensor()).unwrap().flatten_all().unwrap().to_vec1().unwrap();
        (y.flatten_all().unwrap().to_vec1::<f32>().unwrap(), g)
    };
    let (y, g) = grad_of(true);
    let (y_ref, g_ref) = grad_of(false);
    let (dy, dg) = (max_rel(&y, &y_ref), max_rel(&g, &g_ref));
    eprintln!("elu: values {dy:.2e}, gradient {dg:.2e}");
    assert!(dy < 1e-6 && dg < 1e-6, "fused ELU differs: values {dy}, gradient {dg}");
    assert!(
        y_ref.iter().any(|&v| v < -0.5),
        "no negative inputs: the test checks half of ELU"
    );
}
