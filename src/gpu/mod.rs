//! The GPU side of the beam estimate, through wgpu (Vulkan, Metal, DX12, GL): adapter
//! choice ([`open`]), the shared buffer layouts ([`layout`]), free-path sampling in WGSL
//! ([`freepath`]) and the estimator ([`beams::GpuBeams`]). The CPU path in `estimate::cpu`
//! computes the same sums.
pub mod beams;
pub mod buffers;
pub mod freepath;
pub mod layout;

use std::sync::{Arc, Mutex};

use crate::error::{Error, Result};

/// Where the beam estimate runs (`--device`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum DeviceKind {
    /// A hardware adapter if there is one, else the CPU. Software rasterizers (lavapipe,
    /// llvmpipe, WARP) run no faster than the CPU path, so auto does not pick them.
    Auto,
    /// Any adapter, software ones included; an error when there is none.
    Gpu,
    Cpu,
}

/// An open device and what the estimate needs to know about it.
#[derive(Clone)]
pub struct Gpu {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub info: wgpu::AdapterInfo,
    pub limits: wgpu::Limits,
    /// The first validation or out-of-memory error wgpu reported outside an error scope
    /// (wgpu would otherwise panic on it); checked after every submission.
    errors: Arc<Mutex<Option<String>>>,
}

impl Gpu {
    /// "NAME (BACKEND, TYPE)" for the one line that says which adapter runs the estimate.
    pub fn describe(&self) -> String {
        format!(
            "{} ({:?}, {:?})",
            self.info.name, self.info.backend, self.info.device_type
        )
    }

    /// The first error wgpu reported, if any.
    pub fn take_error(&self) -> Option<String> {
        self.errors.lock().unwrap_or_else(|e| e.into_inner()).take()
    }
}

/// Preference among adapters: hardware before software, native APIs before GL.
fn rank(info: &wgpu::AdapterInfo) -> (u8, u8) {
    let ty = match info.device_type {
        wgpu::DeviceType::DiscreteGpu => 0,
        wgpu::DeviceType::IntegratedGpu => 1,
        wgpu::DeviceType::VirtualGpu => 2,
        wgpu::DeviceType::Other => 3,
        wgpu::DeviceType::Cpu => 4,
    };
    let api = u8::from(info.backend == wgpu::Backend::Gl);
    (ty, api)
}

/// Opens the device `kind` asks for: `Ok(None)` means the CPU path. The backends can be
/// narrowed with the `WGPU_BACKEND` environment variable (e.g. `vulkan`).
pub fn open(kind: DeviceKind) -> Result<Option<Gpu>> {
    if kind == DeviceKind::Cpu {
        return Ok(None);
    }
    // GL is asked only when no native API answers: probing EGL is slow and noisy.
    let only = wgpu::Backends::from_env();
    let mut adapters = Vec::new();
    for backends in [wgpu::Backends::PRIMARY, wgpu::Backends::SECONDARY] {
        let backends = only.map_or(backends, |o| o & backends);
        if backends.is_empty() || !adapters.is_empty() {
            continue;
        }
        let mut desc = wgpu::InstanceDescriptor::new_without_display_handle_from_env();
        desc.backends = backends;
        let instance = wgpu::Instance::new(desc);
        adapters = pollster::block_on(instance.enumerate_adapters(backends));
    }
    adapters.sort_by_key(|a| rank(&a.get_info()));
    let pick = adapters
        .into_iter()
        .find(|a| kind == DeviceKind::Gpu || a.get_info().device_type != wgpu::DeviceType::Cpu);
    let Some(adapter) = pick else {
        return match kind {
            DeviceKind::Gpu => Err(Error::Gpu(
                "no GPU adapter found (no Vulkan, Metal, DX12 or GL driver answered; on Debian \
                 `apt-get install mesa-vulkan-drivers libvulkan1` gives a software one)"
                    .into(),
            )),
            _ => Ok(None),
        };
    };
    Gpu::open_adapter(&adapter).map(Some)
}

impl Gpu {
    /// Opens `adapter`'s device, with its full limits, float32 blending where it has it
    /// (primary segments are rasterised then, `gpu::beams`) and its errors and loss
    /// recorded for [`Gpu::take_error`]. The one way ppb opens a device: the estimate's
    /// adapter, or the one that presents `ppb watch`'s window.
    pub fn open_adapter(adapter: &wgpu::Adapter) -> Result<Gpu> {
        let info = adapter.get_info();
        let limits = adapter.limits();
        let desc = wgpu::DeviceDescriptor {
            label: Some("ppb"),
            required_features: adapter.features() & wgpu::Features::FLOAT32_BLENDABLE,
            required_limits: limits.clone(),
            ..Default::default()
        };
        let (device, queue) = pollster::block_on(adapter.request_device(&desc))
            .map_err(|e| Error::Gpu(format!("{}: cannot open the device: {e}", info.name)))?;
        let errors: Arc<Mutex<Option<String>>> = Arc::default();
        let slot = errors.clone();
        device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
            let mut s = slot.lock().unwrap_or_else(|p| p.into_inner());
            s.get_or_insert_with(|| e.to_string());
        }));
        let slot = errors.clone();
        device.set_device_lost_callback(move |reason, msg| {
            let mut s = slot.lock().unwrap_or_else(|p| p.into_inner());
            s.get_or_insert_with(|| format!("device lost ({reason:?}): {msg}"));
        });
        Ok(Gpu {
            device,
            queue,
            info,
            limits,
            errors,
        })
    }
}

/// Parses and validates a kernel's source as wgpu does at pipeline creation (panicking
/// with naga's message), and returns a check that struct `name` has `size` bytes and each
/// named field its offset: shared structs must match their Rust `Pod` types.
#[cfg(test)]
pub(crate) fn validated(source: &str) -> impl Fn(&str, usize, &[(&str, usize)]) {
    let module = naga::front::wgsl::parse_str(source)
        .unwrap_or_else(|e| panic!("{}", e.emit_to_string(source)));
    naga::valid::Validator::new(
        naga::valid::ValidationFlags::all(),
        naga::valid::Capabilities::empty(),
    )
    .validate(&module)
    .unwrap_or_else(|e| panic!("{}", e.emit_to_string(source)));
    move |name, size, fields| {
        let ty = module
            .types
            .iter()
            .find(|(_, t)| t.name.as_deref() == Some(name))
            .unwrap_or_else(|| panic!("struct {name} missing from the shader"))
            .1;
        let naga::TypeInner::Struct { members, span } = &ty.inner else {
            panic!("{name} is not a struct");
        };
        assert_eq!(*span as usize, size, "size of {name}");
        for (f, off) in fields {
            let m = members.iter().find(|m| m.name.as_deref() == Some(*f));
            assert_eq!(
                m.map(|m| m.offset as usize),
                Some(*off),
                "offset of {name}.{f}"
            );
        }
    }
}

/// `source` compiled, with a compute pipeline per entry point, each over one bind group of
/// `bindings`.
pub(crate) fn compute_pipelines(
    dev: &wgpu::Device,
    label: &str,
    source: &str,
    bindings: &wgpu::BindGroupLayout,
    entries: &[&str],
) -> (wgpu::ShaderModule, Vec<wgpu::ComputePipeline>) {
    let module = dev.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(label),
        source: wgpu::ShaderSource::Wgsl(source.into()),
    });
    let layout = dev.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some(label),
        bind_group_layouts: &[Some(bindings)],
        immediate_size: 0,
    });
    let pipelines = entries
        .iter()
        .map(|entry| {
            dev.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(entry),
                layout: Some(&layout),
                module: &module,
                entry_point: Some(entry),
                compilation_options: Default::default(),
                cache: None,
            })
        })
        .collect();
    (module, pipelines)
}

#[cfg(test)]
mod tests {
    use super::beams::SHADER;
    use super::layout::{BeamQuad, Chunk, GridMeta, MediumBox, Params, Segment};
    use super::validated;
    use crate::estimate::beams::BvhNode;
    use crate::estimate::eq2::BeamPiece;
    use std::mem::{offset_of, size_of};

    /// The tube's hash in the shader weighs its ten words by `sampling::HASH_WEIGHTS`,
    /// written there as literals.
    #[test]
    fn shader_hash_weights_match() {
        let body = &SHADER[SHADER.find("fn pair_u(").expect("pair_u in the shader")..];
        let body = &body[..body.find("return").expect("its return")];
        for k in &crate::sampling::HASH_WEIGHTS[..10] {
            assert!(body.contains(&format!("{k:#010x}u")), "{k:#010x} in {body}");
        }
    }

    /// The shader parses and validates (naga, as wgpu does at pipeline creation), and every
    /// struct it shares with the CPU has the Rust `Pod` type's size and field offsets.
    #[test]
    fn shader_validates_and_layouts_match() {
        let check = validated(SHADER);
        check(
            "Segment",
            size_of::<Segment>(),
            &[
                ("dir", offset_of!(Segment, dir)),
                ("t1", offset_of!(Segment, t1)),
                ("beta", offset_of!(Segment, beta)),
                ("tr_first", offset_of!(Segment, tr_first)),
                ("tr_count", offset_of!(Segment, tr_count)),
                ("seed", offset_of!(Segment, seed)),
            ],
        );
        check(
            "BeamPiece",
            size_of::<BeamPiece>(),
            &[
                ("s0", offset_of!(BeamPiece, s0)),
                ("dir", offset_of!(BeamPiece, dir)),
                ("s1", offset_of!(BeamPiece, s1)),
                ("power", offset_of!(BeamPiece, power)),
            ],
        );
        check(
            "BvhNode",
            size_of::<BvhNode>(),
            &[
                ("skip", offset_of!(BvhNode, skip)),
                ("max", offset_of!(BvhNode, max)),
                ("first", offset_of!(BvhNode, first)),
                ("count", offset_of!(BvhNode, count)),
            ],
        );
        check(
            "MediumBox",
            size_of::<MediumBox>(),
            &[
                ("sigma_t", offset_of!(MediumBox, sigma_t)),
                ("g", offset_of!(MediumBox, g)),
                ("albedo", offset_of!(MediumBox, albedo)),
            ],
        );
        check(
            "GridMeta",
            size_of::<GridMeta>(),
            &[
                ("bmin", offset_of!(GridMeta, bmin)),
                ("density_scale", offset_of!(GridMeta, density_scale)),
                ("albedo", offset_of!(GridMeta, albedo)),
                ("background", offset_of!(GridMeta, background)),
                ("table_min", offset_of!(GridMeta, table_min)),
                ("leaf_base", offset_of!(GridMeta, leaf_base)),
                ("table_dim", offset_of!(GridMeta, table_dim)),
                ("table_base", offset_of!(GridMeta, table_base)),
                ("tile_base", offset_of!(GridMeta, tile_base)),
                ("tile_count", offset_of!(GridMeta, tile_count)),
            ],
        );
        check(
            "Params",
            size_of::<Params>(),
            &[
                ("radius", offset_of!(Params, radius)),
                ("box_count", offset_of!(Params, box_count)),
                ("grid_count", offset_of!(Params, grid_count)),
                ("raster_width", offset_of!(Params, raster_width)),
                ("pass_seed", offset_of!(Params, pass_seed)),
                ("track_tr", offset_of!(Params, track_tr)),
                ("walk_budget", offset_of!(Params, walk_budget)),
                ("boxes", offset_of!(Params, boxes)),
                ("grids", offset_of!(Params, grids)),
            ],
        );
        check(
            "BeamQuad",
            size_of::<BeamQuad>(),
            &[
                ("corners", offset_of!(BeamQuad, corners)),
                ("piece", offset_of!(BeamQuad, piece)),
            ],
        );
        check(
            "Chunk",
            size_of::<Chunk>(),
            &[("count", offset_of!(Chunk, count))],
        );
    }
}
