//! `flatport info`.

use flatport::gpu::adapters;

pub fn run() -> anyhow::Result<()> {
    let threads = std::thread::available_parallelism()
        .map(|n| n.get())
        .unwrap_or(1);
    outln!("flatport {}", env!("CARGO_PKG_VERSION"));
    outln!(
        "build: {} ({}-{})",
        if cfg!(debug_assertions) {
            "debug"
        } else {
            "release"
        },
        std::env::consts::ARCH,
        std::env::consts::OS
    );
    outln!("devices:");
    outln!(
        "  cpu: f64 reference, {threads} hardware threads; vector path on {} ({} rows at a time)",
        flatport::engine::cpu::lanes::instruction_set(),
        flatport::engine::cpu::lanes::LANES
    );
    let found = adapters();
    if found.is_empty() {
        outln!(
            "  gpu: no Vulkan adapter found (install mesa-vulkan-drivers for the lavapipe software adapter, \
             or your GPU's Vulkan driver)"
        );
    }
    for (index, a) in found.iter().enumerate() {
        let yes = |b: bool| if b { "yes" } else { "no" };
        outln!(
            "  gpu {index}: {} [{} {}, {}]  (--adapter {index})",
            a.name,
            a.backend,
            a.device_type,
            a.driver
        );
        outln!(
            "       features used: SHADER_F64 {}, SUBGROUP {}, TIMESTAMP_QUERY {}",
            yes(a.f64),
            yes(a.subgroup),
            yes(a.timestamp)
        );
        outln!(
            "       limits used: storage binding {} MiB, uniform binding {} KiB, {} workgroups per dimension",
            a.max_storage_binding >> 20,
            a.max_uniform_binding >> 10,
            a.max_workgroups_per_dimension
        );
    }
    outln!("--device cpu:  the f64 reference on all cores");
    outln!(
        "--device gpu:  the WGSL kernels on a Vulkan adapter above (--adapter INDEX|NAME, else $FLATPORT_ADAPTER,"
    );
    outln!("               else the best: discrete, integrated, virtual, other, then lavapipe)");
    outln!("--device auto: (the default) a hardware GPU when there is one, otherwise the CPU");
    Ok(())
}
