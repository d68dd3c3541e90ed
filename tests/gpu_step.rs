//! What a training step asks of a GPU (wgpu; Mesa lavapipe in CI): how many kernels it launches
//! and that it reads nothing back between logging steps. Launch counts are the host's, the same
//! on every adapter. Its own test binary: the launch observer and the read counters are
//! process-wide, so no other test may run beside it.
#![cfg(feature = "wgpu")]

use burn::tensor::{Device, DeviceKind};
use ctadsa_core::bench::LaunchWatch;
use ctadsa_core::config::Config;
use ctadsa_core::data::case::Case;
use ctadsa_core::data::synth::{SynthConfig, synthesize};
use ctadsa_core::method::train::Trainer;
use ctadsa_ops::readback::Transfers;

mod scratch;
use scratch::scratch;

const QUICK_TOML: &str = include_str!(concat!(env!("CARGO_MANIFEST_DIR"), "/configs/quick.toml"));

/// Kernel launches per step of the quick configuration at most (measured: 41 on 2026-11-30 with
/// the L1 and SSIM means as a sum per workgroup and the sum of those, two launches each; 39 on
/// 2026-11-27 with each in one workgroup, which on 512² views took 0.44 and 0.23 ms of an H200's
/// 6.56 per step; with the whole opacity field as one op and the anchoring term's own gather and
/// scatter; 65 before them, 114 before the anchoring, scale, L1 and
/// loss-total ops, 402 before the fused Adam, linear-layer, SSIM and anchor kernels).
const MAX_LAUNCHES_PER_STEP: f64 = 41.0;

#[test]
fn a_quick_training_step_launches_few_kernels_and_reads_nothing_back() {
    let adapter = ctadsa_render::wgpu_adapter();
    let Ok(name) = adapter else {
        if std::env::var("CTADSA_REQUIRE_WGPU").is_ok_and(|v| v == "1") {
            panic!("CTADSA_REQUIRE_WGPU=1 but {}", adapter.unwrap_err());
        }
        eprintln!("SKIPPED: GPU step launch count not checked: {}", adapter.unwrap_err());
        return;
    };
    eprintln!("wgpu adapter: {name}");
    let dir = scratch("gpu-step");
    synthesize(&SynthConfig::small_procedural("gpu-step"), &dir, &mut |_| {}).expect("synthesis");
    let case = Case::load(&dir).expect("case");
    // Every loss term of the quick configuration active (the anchoring from the first step);
    // densification statistics accumulate (densify.from = 100 is not reached).
    let overrides = ["init.n1=1500", "init.n2=1200", "loss.pa_start=0", "loss.fn_start=0"].map(String::from);
    let cfg = Config::from_toml_str(QUICK_TOML, "configs/quick.toml", &overrides).unwrap();
    let mut trainer = Trainer::new(&case, cfg, Device::wgpu(DeviceKind::DefaultDevice).autodiff()).unwrap();
    trainer.set_log_every(1000);
    for _ in 0..2 {
        trainer.step().unwrap();
    }
    let steps = 5;
    let watch = LaunchWatch::start(false);
    let before = Transfers::now();
    for _ in 0..steps {
        trainer.step().unwrap();
    }
    let transfers = Transfers::now().since(before);
    let launches = watch.take();
    drop(watch);
    let per_step = launches.total() as f64 / steps as f64;
    eprintln!("per step: {per_step} launches, {transfers:?}; {:?}", launches.counts);
    assert_eq!(transfers.reads, 0, "blocking reads in non-logging steps");
    assert!(per_step <= MAX_LAUNCHES_PER_STEP, "{per_step} launches per step (at most {MAX_LAUNCHES_PER_STEP})");
    assert!(per_step >= 10.0, "the observer sees the step's launches ({per_step})");
    // The logging read: one for all the steps since the last.
    trainer.flush_logs().unwrap();
    assert_eq!(Transfers::now().since(before).reads, 1, "one read for the pending logs");
    assert_eq!(trainer.history().len(), 2 + steps, "every step logged");
}
