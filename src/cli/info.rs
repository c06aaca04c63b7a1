//! `flatport info`.

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
    println!("  gpu: not in this version (the wgpu engine is planned; --device accepts only cpu)");
    Ok(())
}
