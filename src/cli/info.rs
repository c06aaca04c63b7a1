//! `flatport info`.

use flatport::gpu::adapters;

pub fn run() -> anyhow::Result<()> {
    let threads = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1);
    println!("flatport {}", env!("CARGO_PKG_VERSION"));
    println!(
        "build: {} ({}-{})",
        if cfg!(debug_assertions) { "debug" } else { "release" },
        std::env::consts::ARCH,
        std::env::consts::OS
    );
    println!("devices:");
    println!("  cpu: f64 reference, {threads} hardware threads");
    let found = adapters();
    if found.is_empty() {
        println!(
            "  gpu: no Vulkan adapter found (install mesa-vulkan-drivers for the lavapipe software adapter, \
             or your GPU's Vulkan driver)"
        );
    }
    for a in &found {
        let yes = |b: bool| if b { "yes" } else { "no" };
        println!("  gpu: {} [{} {}, {}]", a.name, a.backend, a.device_type, a.driver);
        println!(
            "       features used: SHADER_F64 {}, SUBGROUP {}, TIMESTAMP_QUERY {}",
            yes(a.f64),
            yes(a.subgroup),
            yes(a.timestamp)
        );
        println!(
            "       limits used: storage binding {} MiB, {} workgroups per dimension",
            a.max_storage_binding >> 20,
            a.max_workgroups_per_dimension
        );
    }
    println!("--device cpu:  the f64 reference on all cores");
    println!("--device gpu:  the WGSL kernels on a Vulkan adapter above (--adapter NAME, else $FLATPORT_ADAPTER,");
    println!("               else the first hardware GPU, else lavapipe)");
    println!("--device auto: (the default) a hardware GPU when there is one, otherwise the CPU");
    Ok(())
}
