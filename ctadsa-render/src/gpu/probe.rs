//! Whether a usable wgpu adapter (a GPU, or a software Vulkan driver such as Mesa lavapipe)
//! exists: the one burn's default wgpu device comes up on, with what the kernels need.

use burn::backend::read_sync;
use burn_cubecl::cubecl::wgpu::wgpu;

/// What the renderer's kernels need of an adapter that it may lack: the f32 atomic add in
/// storage buffers (`SHADER_FLOAT32_ATOMIC`; Vulkan's `shaderBufferFloat32AtomicAdd`). The
/// kernels bind their accumulators as `atomic<f32>`, so shaders for an adapter without it do not
/// compile (wgpu's OpenGL backend never has it).
pub const REQUIRED_FEATURE: &str = "SHADER_FLOAT32_ATOMIC (f32 atomic add in storage buffers)";

/// The graphics APIs burn's default wgpu device tries, best first (CubeCL's `AutoGraphicsApi`
/// on Linux and Windows; Metal on macOS).
fn api_chain() -> Vec<wgpu::Backend> {
    if cfg!(target_os = "macos") {
        vec![wgpu::Backend::Metal]
    } else {
        vec![wgpu::Backend::Vulkan, wgpu::Backend::Dx12, wgpu::Backend::Gl]
    }
}

/// Held while an instance exists: the Vulkan loader crashes when instances come and go on
/// several threads at once (test threads probe concurrently).
static PROBING: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn adapters(backend: wgpu::Backend) -> Vec<wgpu::Adapter> {
    let _probing = PROBING.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    let instance = wgpu::Instance::new(wgpu::InstanceDescriptor {
        backends: backend.into(),
        ..wgpu::InstanceDescriptor::new_without_display_handle()
    });
    read_sync(instance.enumerate_adapters(backend.into()))
}

/// The adapter the default device lands on: on the first API of the chain with a hardware
/// adapter (else the first with any), its discrete GPU, else integrated, virtual, other, CPU.
fn chosen_adapter() -> Option<wgpu::Adapter> {
    let rank = |t: wgpu::DeviceType| match t {
        wgpu::DeviceType::DiscreteGpu => 0,
        wgpu::DeviceType::IntegratedGpu => 1,
        wgpu::DeviceType::VirtualGpu => 2,
        wgpu::DeviceType::Other => 3,
        wgpu::DeviceType::Cpu => 4,
    };
    let mut software_only = None;
    for api in api_chain() {
        let mut found = adapters(api);
        if found.is_empty() {
            continue;
        }
        found.sort_by_key(|a| rank(a.get_info().device_type));
        let hardware = found.first().is_some_and(|a| a.get_info().device_type != wgpu::DeviceType::Cpu);
        if hardware {
            return found.into_iter().next();
        }
        if software_only.is_none() {
            software_only = found.into_iter().next();
        }
    }
    software_only
}

/// A description of the adapter burn's default wgpu device uses
/// (`"llvmpipe (LLVM 15.0.6, 256 bits) / Vulkan / Cpu / native f32 atomic add"`), or why there
/// is none that the renderer can use: no adapter, or one without [`REQUIRED_FEATURE`] (named
/// in the message).
pub fn wgpu_adapter() -> Result<String, String> {
    let Some(adapter) = chosen_adapter() else {
        return Err("no wgpu adapter found (no GPU driver; for a CPU Vulkan driver install Mesa lavapipe: \
             apt-get install mesa-vulkan-drivers libvulkan1)"
            .to_string());
    };
    let info = adapter.get_info();
    let name = format!("{} / {:?} / {:?}", info.name, info.backend, info.device_type);
    if !adapter.features().contains(wgpu::Features::SHADER_FLOAT32_ATOMIC) {
        return Err(format!(
            "the wgpu adapter {name} lacks {REQUIRED_FEATURE}, which the renderer's GPU kernels need \
             (wgpu's OpenGL backend never has it; a Vulkan driver does: install one, e.g. Mesa lavapipe \
             `apt-get install mesa-vulkan-drivers libvulkan1`, or use --backend ndarray)"
        ));
    }
    Ok(format!("{name} / native f32 atomic add"))
}
