//! The `ppb watch --window` preview: a winit window with a wgpu (Vulkan) surface showing
//! the tone-mapped image. Self-contained on purpose: its own instance, adapter and device,
//! independent of any compute use of wgpu elsewhere.
//!
//! The linear image is uploaded as an Rgba32Float texture (hence Vulkan: wgpu's GL backend
//! cannot sample it) and a full-screen triangle applies the exposure, the sRGB curve and an
//! aspect-preserving fit to the window.
use anyhow::{anyhow, Context, Result};
use std::sync::mpsc::Sender;
use std::sync::Arc;
use winit::application::ApplicationHandler;
use winit::dpi::PhysicalSize;
use winit::event::{ElementState, WindowEvent};
use winit::event_loop::{ActiveEventLoop, EventLoop, EventLoopProxy};
use winit::keyboard::{Key, NamedKey};
use winit::window::WindowId;

use super::live::{Msg, SharedFrame};

/// Exposure change per key press, stops.
const EXPOSURE_STEP: f32 = 0.5;

/// Draws the image, already tone-mapped on the CPU (`output::tone_map`, as the PNG), scaled
/// to fit: the texture holds sRGB bytes, read raw by a linear surface or decoded for an
/// sRGB surface to encode again, so the window shows the PNG's values.
const SHADER: &str = r#"
struct Params { surface: vec2<f32>, image: vec2<f32> };
@group(0) @binding(0) var img: texture_2d<f32>;
@group(0) @binding(1) var<uniform> p: Params;

@vertex
fn vs(@builtin(vertex_index) i: u32) -> @builtin(position) vec4<f32> {
    let xy = vec2<f32>(f32((i << 1u) & 2u), f32(i & 2u));
    return vec4<f32>(xy * 2.0 - 1.0, 0.0, 1.0);
}

@fragment
fn fs(@builtin(position) pos: vec4<f32>) -> @location(0) vec4<f32> {
    let scale = min(p.surface.x / p.image.x, p.surface.y / p.image.y);
    let offset = 0.5 * (p.surface - p.image * scale);
    let q = (pos.xy - offset) / scale;
    if (q.x < 0.0 || q.y < 0.0 || q.x >= p.image.x || q.y >= p.image.y) {
        return vec4<f32>(0.08, 0.08, 0.08, 1.0);
    }
    return vec4<f32>(textureLoad(img, vec2<i32>(q), 0).rgb, 1.0);
}
"#;

/// The event loop before it runs, created on the main thread.
pub struct Window {
    event_loop: EventLoop<()>,
    app: App,
}

impl Window {
    /// Connects to the display; fails with a clear message when there is none.
    pub fn open(shared: SharedFrame, tx: Sender<Msg>) -> Result<Self> {
        #[cfg(all(unix, not(target_os = "macos")))]
        if std::env::var_os("DISPLAY").is_none() {
            return Err(anyhow!(
                "no X display (DISPLAY is not set); run under X11 or Xvfb"
            ));
        }
        let event_loop = EventLoop::<()>::with_user_event()
            .build()
            .context("cannot connect to the display")?;
        let app = App {
            shared,
            tx,
            exposure_offset: 0.0,
            gpu: None,
            shown: (0, 0),
            sized_for: (0, 0),
            error: None,
        };
        Ok(Window { event_loop, app })
    }

    /// Wakes the window from the render thread when a new image is ready.
    pub fn waker(&self) -> Box<dyn Fn() + Send> {
        let proxy: EventLoopProxy<()> = self.event_loop.create_proxy();
        Box::new(move || {
            let _ = proxy.send_event(());
        })
    }

    /// Runs until the window is closed (Esc, Q, or the close button).
    pub fn run(mut self) -> Result<()> {
        self.event_loop
            .run_app(&mut self.app)
            .context("window event loop")?;
        match self.app.error.take() {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }
}

struct App {
    shared: SharedFrame,
    tx: Sender<Msg>,
    /// Key-set exposure on top of the scene's, stops.
    exposure_offset: f32,
    gpu: Option<Presenter>,
    /// Serial and exposure (bits) of the uploaded image.
    shown: (u64, u32),
    /// Image size the window was last sized for.
    sized_for: (u32, u32),
    error: Option<anyhow::Error>,
}

impl ApplicationHandler for App {
    fn resumed(&mut self, el: &ActiveEventLoop) {
        if self.gpu.is_some() {
            return;
        }
        match Presenter::new(el) {
            Ok(g) => self.gpu = Some(g),
            Err(e) => {
                self.error = Some(e);
                el.exit();
            }
        }
    }

    fn user_event(&mut self, _el: &ActiveEventLoop, _: ()) {
        if let Some(g) = &self.gpu {
            g.window.request_redraw();
        }
    }

    fn window_event(&mut self, el: &ActiveEventLoop, _id: WindowId, event: WindowEvent) {
        match event {
            WindowEvent::CloseRequested => el.exit(),
            WindowEvent::Resized(size) => {
                if let Some(g) = &mut self.gpu {
                    g.resize(size);
                }
            }
            WindowEvent::RedrawRequested => self.redraw(),
            WindowEvent::KeyboardInput { event, .. } if event.state == ElementState::Pressed => {
                match event.logical_key.as_ref() {
                    Key::Named(NamedKey::Escape) | Key::Character("q") => el.exit(),
                    Key::Character("+") | Key::Character("=") => self.expose(EXPOSURE_STEP),
                    Key::Character("-") => self.expose(-EXPOSURE_STEP),
                    Key::Character("s") | Key::Character("S") => {
                        let _ = self.tx.send(Msg::Snapshot {
                            exposure: self.exposure(),
                        });
                    }
                    _ => {}
                }
            }
            _ => {}
        }
    }
}

impl App {
    fn exposure(&self) -> f32 {
        let base = self.shared.lock().map(|f| f.exposure).unwrap_or(0.0);
        base + self.exposure_offset
    }

    fn expose(&mut self, stops: f32) {
        self.exposure_offset += stops;
        if let Some(g) = &self.gpu {
            g.window.request_redraw();
        }
    }

    fn redraw(&mut self) {
        let exposure = self.exposure();
        let Some(g) = &mut self.gpu else {
            return;
        };
        let Ok(frame) = self.shared.lock().map(|f| f.clone()) else {
            return;
        };
        let shown = (frame.serial, exposure.to_bits());
        if shown != self.shown && frame.width > 0 && !frame.pixels.is_empty() {
            let rgba = ppb::output::tone_map(&frame.pixels, exposure);
            g.upload(frame.width, frame.height, &rgba);
            self.shown = shown;
            if self.sized_for != (frame.width, frame.height) {
                self.sized_for = (frame.width, frame.height);
                let _ = g
                    .window
                    .request_inner_size(window_size(frame.width, frame.height));
            }
        }
        let error = frame
            .error
            .as_ref()
            .map_or(String::new(), |e| format!(" | error: {e}"));
        g.window.set_title(&format!(
            "ppb watch | {} | pass {} | {:.1} s | beams on {} | exposure {exposure:+.1}{error}",
            frame.scene, frame.passes, frame.seconds, frame.device
        ));
        g.draw();
    }
}

/// The image scaled by a whole factor to about 512 pixels on its longer side.
fn window_size(w: u32, h: u32) -> PhysicalSize<u32> {
    let k = (512 / w.max(h).max(1)).max(1);
    PhysicalSize::new(w * k, h * k)
}

/// The window and everything drawn into it.
struct Presenter {
    window: Arc<winit::window::Window>,
    surface: wgpu::Surface<'static>,
    device: wgpu::Device,
    queue: wgpu::Queue,
    config: wgpu::SurfaceConfiguration,
    pipeline: wgpu::RenderPipeline,
    layout: wgpu::BindGroupLayout,
    params: wgpu::Buffer,
    /// The image texture, its size and its bind group.
    image: Option<(wgpu::Texture, u32, u32, wgpu::BindGroup)>,
}

impl Presenter {
    fn new(el: &ActiveEventLoop) -> Result<Self> {
        let attrs = winit::window::Window::default_attributes()
            .with_title("ppb watch")
            .with_inner_size(PhysicalSize::new(512u32, 512u32));
        let window = Arc::new(el.create_window(attrs).context("creating the window")?);
        let instance = wgpu::Instance::new(wgpu::InstanceDescriptor {
            backends: wgpu::Backends::VULKAN,
            ..wgpu::InstanceDescriptor::new_without_display_handle()
        });
        let surface = instance
            .create_surface(window.clone())
            .context("creating a Vulkan surface for the window")?;
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            compatible_surface: Some(&surface),
            ..Default::default()
        }))
        .context("no Vulkan adapter can present to this window (install mesa-vulkan-drivers)")?;
        let ppb::gpu::Gpu { device, queue, .. } =
            ppb::gpu::Gpu::open_adapter(&adapter).context("creating the Vulkan device")?;
        let size = window.inner_size();
        let config = surface
            .get_default_config(&adapter, size.width.max(1), size.height.max(1))
            .ok_or_else(|| anyhow!("the adapter cannot present to this window"))?;
        surface.configure(&device, &config);
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("ppb watch image"),
            entries: &[
                wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: false },
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 1,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    count: None,
                },
            ],
        });
        let pipeline = pipeline(&device, &layout, config.format);
        let params = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("ppb watch params"),
            size: 16,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        Ok(Presenter {
            window,
            surface,
            device,
            queue,
            config,
            pipeline,
            layout,
            params,
            image: None,
        })
    }

    fn resize(&mut self, size: PhysicalSize<u32>) {
        if size.width > 0 && size.height > 0 {
            self.config.width = size.width;
            self.config.height = size.height;
            self.surface.configure(&self.device, &self.config);
            self.window.request_redraw();
        }
    }

    /// Uploads the tone-mapped image (recreating the texture when its size changed).
    fn upload(&mut self, w: u32, h: u32, rgba: &[[u8; 4]]) {
        if !matches!(&self.image, Some((_, iw, ih, _)) if (*iw, *ih) == (w, h)) {
            let texture = self.device.create_texture(&wgpu::TextureDescriptor {
                label: Some("ppb watch image"),
                size: wgpu::Extent3d {
                    width: w,
                    height: h,
                    depth_or_array_layers: 1,
                },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format: if self.config.format.is_srgb() {
                    wgpu::TextureFormat::Rgba8UnormSrgb
                } else {
                    wgpu::TextureFormat::Rgba8Unorm
                },
                usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
                view_formats: &[],
            });
            let view = texture.create_view(&wgpu::TextureViewDescriptor::default());
            let group = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("ppb watch image"),
                layout: &self.layout,
                entries: &[
                    wgpu::BindGroupEntry {
                        binding: 0,
                        resource: wgpu::BindingResource::TextureView(&view),
                    },
                    wgpu::BindGroupEntry {
                        binding: 1,
                        resource: self.params.as_entire_binding(),
                    },
                ],
            });
            self.image = Some((texture, w, h, group));
        }
        let Some((texture, ..)) = &self.image else {
            return;
        };
        self.queue.write_texture(
            wgpu::TexelCopyTextureInfo {
                texture,
                mip_level: 0,
                origin: wgpu::Origin3d::ZERO,
                aspect: wgpu::TextureAspect::All,
            },
            bytemuck::cast_slice(rgba),
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(w * 4),
                rows_per_image: Some(h),
            },
            wgpu::Extent3d {
                width: w,
                height: h,
                depth_or_array_layers: 1,
            },
        );
    }

    fn draw(&mut self) {
        let Some((_, w, h, group)) = &self.image else {
            return;
        };
        let frame = match self.surface.get_current_texture() {
            wgpu::CurrentSurfaceTexture::Success(f)
            | wgpu::CurrentSurfaceTexture::Suboptimal(f) => f,
            wgpu::CurrentSurfaceTexture::Outdated | wgpu::CurrentSurfaceTexture::Lost => {
                self.surface.configure(&self.device, &self.config);
                self.window.request_redraw();
                return;
            }
            _ => return,
        };
        let params: [f32; 4] = [
            self.config.width as f32,
            self.config.height as f32,
            *w as f32,
            *h as f32,
        ];
        self.queue
            .write_buffer(&self.params, 0, bytemuck::cast_slice(&params));
        let view = frame
            .texture
            .create_view(&wgpu::TextureViewDescriptor::default());
        let mut encoder = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor::default());
        {
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("ppb watch"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: &view,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color::BLACK),
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: None,
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, group, &[]);
            pass.draw(0..3, 0..1);
        }
        self.queue.submit([encoder.finish()]);
        self.window.pre_present_notify();
        self.queue.present(frame);
    }
}

fn pipeline(
    device: &wgpu::Device,
    layout: &wgpu::BindGroupLayout,
    format: wgpu::TextureFormat,
) -> wgpu::RenderPipeline {
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some("ppb watch"),
        source: wgpu::ShaderSource::Wgsl(SHADER.into()),
    });
    let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some("ppb watch"),
        bind_group_layouts: &[Some(layout)],
        immediate_size: 0,
    });
    device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: Some("ppb watch"),
        layout: Some(&pipeline_layout),
        vertex: wgpu::VertexState {
            module: &module,
            entry_point: Some("vs"),
            compilation_options: Default::default(),
            buffers: &[],
        },
        primitive: wgpu::PrimitiveState::default(),
        depth_stencil: None,
        multisample: wgpu::MultisampleState::default(),
        fragment: Some(wgpu::FragmentState {
            module: &module,
            entry_point: Some("fs"),
            compilation_options: Default::default(),
            targets: &[Some(wgpu::ColorTargetState {
                format,
                blend: None,
                write_mask: wgpu::ColorWrites::ALL,
            })],
        }),
        multiview_mask: None,
        cache: None,
    })
}
