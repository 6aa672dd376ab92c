//! The one place that picks where tensors live and how many CPU threads libtorch uses.
//!
//! `learner.device = "auto"` (the default) runs the learner on CUDA when libtorch sees a
//! GPU *and* a step's largest part, the critic over every sampled action (MPO) or every
//! state (V-MPO), summed over a population's members, is at least `GPU_MIN_STEP_MACS`
//! multiply-adds: a small step is bound
//! by kernel launches, and on the lent H100 the Deep Sea Treasure step (about 2e7
//! multiply-adds) took 23-47 ms against a few on two CPU cores, while the humanoid step
//! (4e10) took 10 ms against 1.2 s. `cpu` and `cuda` force the choice. Tests construct
//! learners with `tch::Device::Cpu` explicitly.
//!
//! `tune_allocator` keeps freed tensor memory in the process: a learner step allocates
//! and frees the same large activations every step, and glibc's defaults hand each of
//! them back to the kernel (mmap/munmap, or a trimmed heap), so every step paid again
//! for zeroing and faulting the pages in: a quarter of the humanoid-size step.

use tch::Device;

use crate::core::learner_config::{ConfigError, DeviceChoice, LearnerConfig};
use crate::core::nets::{ActionKind, LearnerDims};

/// Steps smaller than this many multiply-adds stay on the CPU under `auto`.
pub const GPU_MIN_STEP_MACS: f64 = 1e9;

/// CUDA device 0 when available, else the CPU (benchmarks measure on what is there).
pub fn learner_device() -> Device {
    Device::cuda_if_available()
}

/// Multiply-adds of the critic pass over every sampled action (MO-MPO: (T+1) B M rows,
/// or A rows per state for discrete actions) or every state (MO-V-MPO: (T+1) B rows):
/// the part of a step that grows with the networks and the batch.
pub fn critic_step_macs(cfg: &LearnerConfig, dims: &LearnerDims) -> f64 {
    let s = cfg.shared();
    let states = ((s.sequence_length + 1) * s.batch_size) as f64;
    let rows = if cfg.algorithm.on_policy() {
        states
    } else {
        match dims.action {
            ActionKind::Continuous { .. } => states * cfg.mpo.num_samples as f64,
            ActionKind::Discrete { n } => states * n as f64,
        }
    };
    let layers = &cfg.network.critic_layers;
    let input = (dims.obs_dim + dims.action.critic_input_dim()) as f64;
    let first = input * layers[0] as f64;
    let rest: f64 = layers.windows(2).map(|w| (w[0] * w[1]) as f64).sum::<f64>()
        + *layers.last().unwrap_or(&0) as f64;
    rows * (first + rest)
}

/// Whether `auto` puts a learner of `members` members of `cfg` on a GPU when there is
/// one: a population's step does every member's critic pass, so it is `members` times
/// one member's size.
pub fn step_fills_a_gpu(cfg: &LearnerConfig, dims: &LearnerDims, members: usize) -> bool {
    critic_step_macs(cfg, dims) * members as f64 >= GPU_MIN_STEP_MACS
}

/// The device of a learner of `members` members of `cfg` (see the module docs).
pub fn choose_device(
    cfg: &LearnerConfig,
    dims: &LearnerDims,
    members: usize,
) -> Result<Device, ConfigError> {
    let gpu = tch::Cuda::is_available();
    match cfg.device {
        DeviceChoice::Cpu => Ok(Device::Cpu),
        DeviceChoice::Cuda if gpu => Ok(Device::Cuda(0)),
        DeviceChoice::Cuda => Err(ConfigError::Invalid {
            field: "learner.device".into(),
            requirement: "\"cpu\" or \"auto\" on a machine where libtorch sees no GPU".into(),
            got: "\"cuda\"".into(),
        }),
        DeviceChoice::Auto if gpu && step_fills_a_gpu(cfg, dims, members) => Ok(Device::Cuda(0)),
        DeviceChoice::Auto => Ok(Device::Cpu),
    }
}

/// Sets libtorch's intra-op thread count: `requested`, or every available core.
/// Returns the number that was set. The setting is process-wide.
pub fn configure_threads(requested: Option<usize>) -> usize {
    let n = requested.unwrap_or_else(|| {
        std::thread::available_parallelism()
            .map(|n| n.get())
            .unwrap_or(1)
    });
    tch::set_num_threads(i32::try_from(n).unwrap_or(i32::MAX));
    n
}

/// Waits for queued GPU work so wall-clock timings are honest (no-op on CPU).
pub fn synchronize(device: Device) {
    if let Device::Cuda(index) = device {
        tch::Cuda::synchronize(index as i64);
    }
}

/// Makes glibc keep freed memory for reuse instead of returning it to the kernel: no
/// mmap'd chunks (libtorch's large activations come from the heap) and no heap
/// trimming. Threads keep glibc's own arenas: with one arena for the process, the two
/// learners of a `parallel = 2` sweep waited on its lock at every tensor allocation
/// (about 4,700 futex waits per second per learner) and the quick sweep took 93 s
/// instead of 63 s; a lone learner runs as fast either way. Process-wide;
/// call once at start-up, before threads are spawned (the CLI and the benches do).
/// The resident size then stays at the peak of a step, which a learner reaches every
/// step anyway. A no-op where the C library is not glibc.
pub fn tune_allocator() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only changes allocator parameters; called before other threads exist.
    unsafe {
        libc::mallopt(libc::M_MMAP_MAX, 0);
        libc::mallopt(libc::M_TRIM_THRESHOLD, i32::MAX);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::learner_config::NetworkConfig;

    fn dims(obs_dim: i64, action: ActionKind) -> LearnerDims {
        LearnerDims {
            action_bounds: None,
            obs_dim,
            action,
            reward_names: vec!["task".into()],
            obs_leaves: Vec::new(),
        }
    }

    #[test]
    fn auto_keeps_small_networks_on_the_cpu_and_sizes_the_humanoid_step() {
        // Deep Sea Treasure (A.2): T = 1, B = 128, 4 actions, critic (128, 128), obs 2:
        // 2 * 128 * 4 rows * (6 * 128 + 128 * 128 + 128) = 1024 * 17280 ~ 1.8e7.
        let mut dst = LearnerConfig {
            network: NetworkConfig {
                critic_layers: vec![128, 128],
                ..NetworkConfig::default()
            },
            ..LearnerConfig::default()
        };
        dst.mpo.retrace_length = 1;
        dst.mpo.batch_size = 128;
        assert_eq!(
            critic_step_macs(&dst, &dims(2, ActionKind::Discrete { n: 4 })),
            1024.0 * 17280.0
        );
        let dst_dims = dims(2, ActionKind::Discrete { n: 4 });
        assert_eq!(choose_device(&dst, &dst_dims, 1).unwrap(), Device::Cpu);
        // The full Fig. 5 grid as one population (39 members, 6.9e8) stays small; 57
        // members (1.009e9) would fill a GPU.
        assert!(!step_fills_a_gpu(&dst, &dst_dims, 56));
        assert!(step_fills_a_gpu(&dst, &dst_dims, 57));
        // Humanoid run (Table 3): 9 * 512 * 20 rows * (88 * 500 + 500 * 500 + 500 * 400 + 400).
        let mut humanoid = LearnerConfig {
            network: NetworkConfig {
                critic_layers: vec![500, 500, 400],
                ..NetworkConfig::default()
            },
            ..LearnerConfig::default()
        };
        let macs = critic_step_macs(&humanoid, &dims(67, ActionKind::Continuous { dim: 21 }));
        assert_eq!(macs, 92160.0 * 494_400.0);
        assert!(macs > GPU_MIN_STEP_MACS);
        humanoid.device = DeviceChoice::Cpu;
        assert_eq!(
            choose_device(&humanoid, &dims(67, ActionKind::Continuous { dim: 21 }), 1).unwrap(),
            Device::Cpu
        );
        humanoid.device = DeviceChoice::Cuda;
        let got = choose_device(&humanoid, &dims(67, ActionKind::Continuous { dim: 21 }), 1);
        if tch::Cuda::is_available() {
            assert_eq!(got.unwrap(), Device::Cuda(0));
        } else {
            assert_eq!(
                got.unwrap_err().to_string(),
                r#"learner.device must be "cpu" or "auto" on a machine where libtorch sees no GPU, got "cuda""#
            );
        }
    }
}
