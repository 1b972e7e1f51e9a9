//! Vulkan instance: loads libvulkan at run time (once per process), enables `VK_LAYER_KHRONOS_validation` when asked, and records
//! every validation message (warning or error) so tests can fail on any of them.

use super::error::{GpuError, GpuResult, VkCheck};
use ash::vk;
use std::ffi::{c_void, CStr};
use std::sync::{Arc, Mutex, OnceLock};

pub const VALIDATION_LAYER: &CStr = c"VK_LAYER_KHRONOS_validation";

/// Validation messages collected by the debug messenger.
pub type MessageLog = Arc<Mutex<Vec<String>>>;

pub struct InstanceShared {
    pub entry: ash::Entry,
    pub raw: ash::Instance,
    debug: Option<(ash::ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT)>,
    pub messages: MessageLog,
    pub validation_enabled: bool,
    pub debug_utils: bool,
}

unsafe extern "system" fn on_message(
    severity: vk::DebugUtilsMessageSeverityFlagsEXT,
    _ty: vk::DebugUtilsMessageTypeFlagsEXT,
    data: *const vk::DebugUtilsMessengerCallbackDataEXT<'_>,
    user: *mut c_void,
) -> vk::Bool32 {
    // SAFETY: the loader passes valid callback data; `user` is the MessageLog's Mutex, kept alive by
    // InstanceShared for as long as the messenger exists.
    let text = unsafe {
        let d = &*data;
        if d.p_message.is_null() {
            String::from("(no message)")
        } else {
            CStr::from_ptr(d.p_message).to_string_lossy().into_owned()
        }
    };
    let line = format!("[{severity:?}] {text}");
    log::warn!("vulkan: {line}");
    let log = unsafe { &*(user as *const Mutex<Vec<String>>) };
    if let Ok(mut v) = log.lock() {
        v.push(line);
    }
    vk::FALSE
}

/// Whether the Khronos validation layer is installed.
pub fn validation_available(entry: &ash::Entry) -> bool {
    validation_layer_version(entry).is_some()
}

/// The installed validation layer's Vulkan version (`spec_version`), if it is installed.
pub fn validation_layer_version(entry: &ash::Entry) -> Option<u32> {
    unsafe { entry.enumerate_instance_layer_properties() }
        .unwrap_or_default()
        .iter()
        .find(|l| l.layer_name_as_c_str().is_ok_and(|n| n == VALIDATION_LAYER))
        .map(|l| l.spec_version)
}

/// The Vulkan loader, loaded once per process and never unloaded. Loading it per context meant that the last
/// context to go (tests create and drop them on several threads at once) unloaded the loader, and with it the
/// driver and layer libraries, possibly while a driver thread still ran their code: an unexplained segfault in one
/// H100 run of the suite (docs/benchmarks.md) fits that pattern. One load also makes each context cheaper.
///
/// With the loader it pins the drivers: see [`pin_drivers`].
pub fn load_entry() -> GpuResult<ash::Entry> {
    static ENTRY: OnceLock<Result<ash::Entry, String>> = OnceLock::new();
    ENTRY
        .get_or_init(|| {
            // SAFETY: loading the system Vulkan loader; nothing else in the process has loaded a conflicting one.
            let entry = unsafe { ash::Entry::load() }.map_err(|e| e.to_string())?;
            pin_drivers(&entry);
            Ok(entry)
        })
        .clone()
        .map_err(GpuError::Loader)
}

/// Creates one instance that is never destroyed, so that the loader keeps the drivers (ICD libraries) loaded for
/// the life of the process. The loader loads each driver when an instance is created and unloads it when the last
/// instance goes. NVIDIA's driver takes a block of static TLS each time it is loaded, and glibc does not give it
/// back on unload: on an H100 (driver 580) the 34th instance created one after another in a process failed with
/// "libnvidia-tls.so: cannot allocate memory in static TLS block" and the loader found no driver
/// (docs/benchmarks.md). The `msnerf` commands open one context per process; the test suite, which opens one per
/// test, hit it, and so would any program that uses the library that way. The instance has no
/// layers and no extensions; when it cannot be created, nothing is pinned and the context's own instance creation
/// reports the error. Layers that the environment or the system enables implicitly (`VK_INSTANCE_LAYERS`, implicit
/// layer manifests) load into this instance too and stay loaded; only the drivers found at the first load are pinned.
fn pin_drivers(entry: &ash::Entry) {
    let app = vk::ApplicationInfo::default().application_name(c"msnerf driver pin").api_version(vk::API_VERSION_1_3);
    // SAFETY: a plain instance, never destroyed on purpose.
    match unsafe { entry.create_instance(&vk::InstanceCreateInfo::default().application_info(&app), None) } {
        // `ash::Instance` has no destructor: dropping the handle leaves the instance alive.
        Ok(_instance) => DRIVERS_PINNED.store(true, std::sync::atomic::Ordering::Relaxed),
        Err(e) => log::debug!("no instance to pin the drivers with: {e}"),
    }
}

static DRIVERS_PINNED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Whether this process holds the instance that keeps the drivers loaded ([`pin_drivers`]).
pub fn drivers_pinned() -> bool {
    DRIVERS_PINNED.load(std::sync::atomic::Ordering::Relaxed)
}

impl InstanceShared {
    pub fn new(validation: bool) -> GpuResult<Self> {
        let entry = load_entry()?;
        let ext_names: Vec<String> = unsafe { entry.enumerate_instance_extension_properties(None) }
            .vk("vkEnumerateInstanceExtensionProperties")?
            .iter()
            .filter_map(|e| e.extension_name_as_c_str().ok().map(|c| c.to_string_lossy().into_owned()))
            .collect();
        let debug_utils = ext_names.iter().any(|e| e.as_bytes() == ash::ext::debug_utils::NAME.to_bytes());
        let app = vk::ApplicationInfo::default()
            .application_name(c"msnerf")
            .engine_name(c"msnerf")
            .api_version(vk::API_VERSION_1_3);
        let layers: Vec<*const i8> = if validation { vec![VALIDATION_LAYER.as_ptr()] } else { vec![] };
        let exts: Vec<*const i8> = if debug_utils { vec![ash::ext::debug_utils::NAME.as_ptr()] } else { vec![] };
        let info = vk::InstanceCreateInfo::default()
            .application_info(&app)
            .enabled_layer_names(&layers)
            .enabled_extension_names(&exts);
        let raw = match unsafe { entry.create_instance(&info, None) } {
            Ok(i) => i,
            Err(vk::Result::ERROR_INCOMPATIBLE_DRIVER) => {
                return Err(GpuError::NoDevice(" (the loader found no compatible driver)".into()))
            }
            Err(res) => return Err(GpuError::Vulkan { op: "vkCreateInstance", res }),
        };
        let messages: MessageLog = Arc::new(Mutex::new(Vec::new()));
        let debug = if debug_utils {
            let loader = ash::ext::debug_utils::Instance::new(&entry, &raw);
            let info = vk::DebugUtilsMessengerCreateInfoEXT::default()
                .message_severity(
                    vk::DebugUtilsMessageSeverityFlagsEXT::WARNING | vk::DebugUtilsMessageSeverityFlagsEXT::ERROR,
                )
                .message_type(
                    vk::DebugUtilsMessageTypeFlagsEXT::GENERAL
                        | vk::DebugUtilsMessageTypeFlagsEXT::VALIDATION
                        | vk::DebugUtilsMessageTypeFlagsEXT::PERFORMANCE,
                )
                .pfn_user_callback(Some(on_message))
                .user_data(Arc::as_ptr(&messages) as *mut c_void);
            let m = unsafe { loader.create_debug_utils_messenger(&info, None) }.vk("vkCreateDebugUtilsMessengerEXT")?;
            Some((loader, m))
        } else {
            None
        };
        Ok(Self { entry, raw, debug, messages, validation_enabled: validation, debug_utils })
    }
}

impl Drop for InstanceShared {
    fn drop(&mut self) {
        // SAFETY: the device and every child object were destroyed before (DeviceShared drops first).
        unsafe {
            if let Some((loader, m)) = self.debug.take() {
                loader.destroy_debug_utils_messenger(m, None);
            }
            self.raw.destroy_instance(None);
        }
    }
}
