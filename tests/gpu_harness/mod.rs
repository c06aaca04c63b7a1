//! What the GPU test files share: opening an engine on the Vulkan adapter (lavapipe in CI), which
//! fails the run when `CI` is set and there is none, and a small reproducible random source.
#![allow(dead_code)]

use flatport::gpu::{GpuContext, GpuEngine, Precision};

/// The GPU engine at `precision`, or `None` (with a note) when there is no adapter outside CI.
pub fn engine(precision: Precision) -> Option<GpuEngine> {
    engine_with(precision, true)
}

/// As [`engine`]; `map_storage: false` forces the staging copies of discrete GPUs.
pub fn engine_with(precision: Precision, map_storage: bool) -> Option<GpuEngine> {
    match GpuContext::open(None, map_storage) {
        Ok(context) => {
            eprintln!(
                "GPU adapter: {} ({}), {precision}",
                context.adapter().name,
                context.adapter().driver
            );
            Some(
                GpuEngine::new(context, precision)
                    .expect("lavapipe and the GPUs we test have SHADER_F64"),
            )
        }
        Err(e) if std::env::var_os("CI").is_none() => {
            eprintln!("SKIPPED (no Vulkan adapter; CI fails here instead): {e}");
            None
        }
        Err(e) => panic!("CI needs a Vulkan adapter (scripts/test.sh installs lavapipe): {e}"),
    }
}

/// xorshift64*: reproducible random batches without a dependency.
pub struct Random(pub u64);

impl Random {
    pub fn uniform(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
    }

    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.uniform()
    }
}
