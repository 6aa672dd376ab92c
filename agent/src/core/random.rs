//! Per-run random streams: every random number a run draws after its networks are
//! built comes from a stream keyed by the run's seed and the purpose of the draw,
//! never from libtorch's one global generator, so that runs sharing a process (a
//! sweep with `parallel > 1`, a video recorder beside the actors) cannot change each
//! other's numbers.
//!
//! A stream is ChaCha8 keyed by `(seed, purpose, index)`; its 64-bit stream id is a
//! counter (the learner step, the actor's act call), so the numbers of step n do not
//! depend on how many were drawn before it: a resumed run can take up step n without
//! replaying steps 0..n. Normals come from `rand_distr`'s Ziggurat sampler, uniforms
//! from `rand`'s, drawn on the host and moved to the device.
//!
//! tch 0.26 exposes no `at::Generator`, so network initialisation (`nn::Init`) still
//! draws from the global generator: [`seeded_init`] seeds it and builds under one
//! process-wide lock, which makes the global generator a per-run stream for exactly
//! the duration of a build.

use rand::{Rng, RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use std::sync::Mutex;
use tch::{Device, Kind, Tensor};

/// What a stream's numbers are for; part of the key, so two purposes of one run
/// never share numbers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Purpose {
    /// The learner's sampled actions `xi [M, N, D]` (policy evaluation, E-step).
    LearnerNoise,
    /// The mocap torso's latent noise in a learner step.
    LatentNoise,
    /// Sampled actions (and latents) of one actor; `index` is the actor number.
    Acting,
    /// Sampled actions of `Learner::act` (tests and tools acting with the learner).
    LearnerActing,
    /// Which snippets the replay samples.
    Replay,
    /// The shuffle of a V-MPO batch's unrolls into minibatches; `index` is the epoch.
    Minibatches,
    /// The preference (grid point) of each new episode of one actor's instances
    /// (`index` is the actor number; counter: the actor's step).
    ActingPreference,
    /// The grid points a conditioned learner trains its batch's snippets at.
    LearnerPreference,
    /// Seeds of the env sessions an actor makes after its first; `index` is the
    /// actor number, the counter its act count.
    EnvSeeds,
}

impl Purpose {
    fn code(self) -> u64 {
        match self {
            Purpose::LearnerNoise => 1,
            Purpose::LatentNoise => 2,
            Purpose::Acting => 3,
            Purpose::LearnerActing => 4,
            Purpose::Replay => 5,
            // Codes are fixed once published: a new purpose takes the next free one.
            Purpose::Minibatches => 6,
            Purpose::ActingPreference => 7,
            Purpose::LearnerPreference => 8,
            Purpose::EnvSeeds => 9,
        }
    }
}

/// Names one stream of one run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StreamKey {
    /// The run's seed (`seed` or `learner.seed`).
    pub seed: u64,
    /// What the numbers are for.
    pub purpose: Purpose,
    /// Which of several streams of that purpose (the actor number), else 0.
    pub index: u64,
}

impl StreamKey {
    /// Stream `index` of `purpose` for `seed`.
    pub fn new(seed: u64, purpose: Purpose, index: u64) -> Self {
        Self {
            seed,
            purpose,
            index,
        }
    }

    /// The generator at counter `counter` (a learner step, an act call).
    pub fn at(self, counter: u64) -> RandomStream {
        let mut rng = self.rng();
        rng.set_stream(counter);
        RandomStream { rng }
    }

    /// One seed below 2^31 (what every simulator backend takes) at `counter`.
    pub fn seed_at(self, counter: u64) -> u64 {
        let mut rng = self.rng();
        rng.set_stream(counter);
        rng.next_u64() >> 33
    }

    /// The raw generator of this key at counter 0.
    pub fn rng(self) -> ChaCha8Rng {
        // The key bytes are the three fields and a constant tag: distinct fields give
        // distinct ChaCha keys, hence independent streams.
        let mut key = [0u8; 32];
        key[..8].copy_from_slice(&self.seed.to_le_bytes());
        key[8..16].copy_from_slice(&self.purpose.code().to_le_bytes());
        key[16..24].copy_from_slice(&self.index.to_le_bytes());
        key[24..].copy_from_slice(b"mo-mpo\0\0");
        ChaCha8Rng::from_seed(key)
    }
}

/// Draws tensors from one keyed stream, in order.
#[derive(Debug, Clone)]
pub struct RandomStream {
    rng: ChaCha8Rng,
}

impl RandomStream {
    /// Standard normals of `shape`, f32 on `device`.
    pub fn normal(&mut self, shape: &[i64], device: Device) -> Tensor {
        let values: Vec<f32> = (0..numel(shape))
            .map(|_| self.rng.sample(StandardNormal))
            .collect();
        to_tensor(&values, shape, device)
    }

    /// An integer uniform in `0..n` (n > 0).
    pub fn below(&mut self, n: u64) -> u64 {
        self.rng.random_range(0..n)
    }

    /// Uniforms in [0, 1) of `shape`, f32 on `device`.
    pub fn uniform(&mut self, shape: &[i64], device: Device) -> Tensor {
        let values: Vec<f32> = (0..numel(shape)).map(|_| self.rng.random()).collect();
        to_tensor(&values, shape, device)
    }
}

fn numel(shape: &[i64]) -> usize {
    shape.iter().product::<i64>().max(0) as usize
}

fn to_tensor(values: &[f32], shape: &[i64], device: Device) -> Tensor {
    Tensor::from_slice(values)
        .reshape(shape)
        .to_kind(Kind::Float)
        .to_device(device)
}

static GLOBAL_GENERATOR: Mutex<()> = Mutex::new(());

/// Runs `build` with libtorch's global generator seeded by `seed` and held by no
/// one else: network initialisation of one run, unaffected by the draws of any
/// other run in the process. Nothing else in the agent draws from that generator.
pub fn seeded_init<T>(seed: u64, build: impl FnOnce() -> T) -> T {
    let _held = GLOBAL_GENERATOR.lock().unwrap_or_else(|e| e.into_inner());
    tch::manual_seed(seed as i64);
    build()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn draw(key: StreamKey, counter: u64) -> Vec<f32> {
        let t = key.at(counter).normal(&[3, 4], Device::Cpu);
        Vec::<f32>::try_from(t.flatten(0, -1)).unwrap()
    }

    #[test]
    fn streams_are_pure_functions_of_key_and_counter() {
        let key = StreamKey::new(7, Purpose::LearnerNoise, 0);
        assert_eq!(draw(key, 5), draw(key, 5));
        // Counter, seed, purpose and index each select another stream.
        assert_ne!(draw(key, 5), draw(key, 6));
        assert_ne!(
            draw(key, 5),
            draw(StreamKey::new(8, Purpose::LearnerNoise, 0), 5)
        );
        assert_ne!(draw(key, 5), draw(StreamKey::new(7, Purpose::Acting, 0), 5));
        assert_ne!(
            draw(key, 5),
            draw(StreamKey::new(7, Purpose::LearnerNoise, 1), 5)
        );
    }

    #[test]
    fn normals_and_uniforms_have_their_moments() {
        // 40,000 draws: the sample mean's standard error is 0.005 for N(0, 1) and
        // 0.0014 for U[0, 1); the bounds are about 6 standard errors wide.
        let mut s = StreamKey::new(1, Purpose::Replay, 0).at(0);
        let n = s.normal(&[40_000], Device::Cpu);
        assert!(n.mean(Kind::Double).double_value(&[]).abs() < 0.03);
        assert!((n.std(true).double_value(&[]) - 1.0).abs() < 0.03);
        let u = s.uniform(&[40_000], Device::Cpu);
        assert!((u.mean(Kind::Double).double_value(&[]) - 0.5).abs() < 0.01);
        assert!(u.min().double_value(&[]) >= 0.0 && u.max().double_value(&[]) < 1.0);
    }

    #[test]
    fn seeded_init_repeats_its_draws() {
        let a = seeded_init(3, || Tensor::randn([5], (Kind::Float, Device::Cpu)));
        let b = seeded_init(3, || Tensor::randn([5], (Kind::Float, Device::Cpu)));
        assert!(a.equal(&b));
    }
}
