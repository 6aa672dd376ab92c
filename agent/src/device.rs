//! The one place that picks where tensors live and how many CPU threads libtorch uses.
//!
//! The learner runs on CUDA automatically when the libtorch build sees a GPU, else on
//! the CPU. Tests construct learners with `tch::Device::Cpu` explicitly.

use tch::Device;

/// CUDA device 0 when available, else the CPU.
pub fn learner_device() -> Device {
    Device::cuda_if_available()
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
