//! Whether a wgpu adapter (a GPU, or a software Vulkan driver such as Mesa lavapipe) exists.

use burn::backend::read_sync;
use burn_cubecl::cubecl::wgpu::wgpu;

/// A description of the first wgpu adapter and whether it adds f32 atomically in hardware
/// (`"llvmpipe (LLVM 15.0.6, 256 bits) / Vulkan / Cpu / native f32 atomic add"`), or why there is
/// none.
pub fn wgpu_adapter() -> Result<String, String> {
    let instance = wgpu::Instance::default();
    let adapters = read_sync(instance.enumerate_adapters(wgpu::Backends::all()));
    adapters
        .first()
        .map(|a| {
            let info = a.get_info();
            let add = if a.features().contains(wgpu::Features::SHADER_FLOAT32_ATOMIC) {
                "native f32 atomic add"
            } else {
                "f32 atomic add by compare-and-swap"
            };
            format!("{} / {:?} / {:?} / {add}", info.name, info.backend, info.device_type)
        })
        .ok_or_else(|| {
            "no wgpu adapter found (no GPU driver; for a CPU Vulkan driver install Mesa lavapipe: \
             apt-get install mesa-vulkan-drivers libvulkan1)"
                .to_string()
        })
}
