//! Primary segments rasterised as beam quads (the original PPB's way): each beam a film
//! rectangle, a fragment per covered pixel evaluating eq. 2 for that pixel's primary
//! segment into an additively blended float32 target, and its nested half-radius
//! difference into a second one.
use rayon::prelude::*;

use super::GpuBeams;
use crate::error::Result;
use crate::estimate::splat::{reach_per_radius, Line};
use crate::estimate::TracedPass;
use crate::gpu::buffers::{bind_group, buffer_entry, Grow, READ, UNIFORM};
use crate::gpu::layout::{BeamQuad, SegmentUpload};
use crate::transport::camera::Pinhole;

/// What rasterising primary segments needs.
pub(super) struct Raster {
    pub(super) pipeline: wgpu::RenderPipeline,
    pub(super) layout: wgpu::BindGroupLayout,
    /// The estimate's and the nested difference's targets.
    pub(super) targets: [wgpu::TextureView; 2],
    pub(super) primaries: Grow,
    pub(super) quads: Grow,
    /// [`reach_per_radius`] of the camera.
    pub(super) reach: f32,
}

/// The target rasterised primary sums blend into (`render`), or a 1x1 stand-in.
pub(super) fn sums_texture(
    dev: &wgpu::Device,
    width: u32,
    height: u32,
    render: bool,
) -> wgpu::TextureView {
    let mut usage = wgpu::TextureUsages::TEXTURE_BINDING;
    if render {
        usage |= wgpu::TextureUsages::RENDER_ATTACHMENT;
    }
    dev.create_texture(&wgpu::TextureDescriptor {
        label: Some("primary sums"),
        size: wgpu::Extent3d {
            width,
            height,
            depth_or_array_layers: 1,
        },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: wgpu::TextureFormat::Rgba32Float,
        usage,
        view_formats: &[],
    })
    .create_view(&wgpu::TextureViewDescriptor::default())
}

/// Bindings of `quad_vs` and `quad_fs`.
pub(super) fn quad_layout(dev: &wgpu::Device) -> wgpu::BindGroupLayout {
    let frag = wgpu::ShaderStages::FRAGMENT;
    let entries = [
        buffer_entry(0, frag, UNIFORM, false),
        buffer_entry(4, frag, READ, false),
        buffer_entry(7, frag, READ, false),
        buffer_entry(11, frag, READ, false),
        buffer_entry(12, frag | wgpu::ShaderStages::VERTEX, READ, false),
        buffer_entry(13, frag, READ, false),
        buffer_entry(14, frag, UNIFORM, false),
    ];
    dev.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some("beam quads"),
        entries: &entries,
    })
}

/// Beam quads blended additively into the float32 primary target.
pub(super) fn quad_pipeline(
    dev: &wgpu::Device,
    module: &wgpu::ShaderModule,
    bindings: &wgpu::BindGroupLayout,
) -> wgpu::RenderPipeline {
    let layout = dev.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some("beam quads"),
        bind_group_layouts: &[Some(bindings)],
        immediate_size: 0,
    });
    let add = wgpu::BlendComponent {
        src_factor: wgpu::BlendFactor::One,
        dst_factor: wgpu::BlendFactor::One,
        operation: wgpu::BlendOperation::Add,
    };
    dev.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: Some("beam quads"),
        layout: Some(&layout),
        vertex: wgpu::VertexState {
            module,
            entry_point: Some("quad_vs"),
            compilation_options: Default::default(),
            buffers: &[],
        },
        primitive: wgpu::PrimitiveState::default(),
        depth_stencil: None,
        multisample: wgpu::MultisampleState::default(),
        fragment: Some(wgpu::FragmentState {
            module,
            entry_point: Some("quad_fs"),
            compilation_options: Default::default(),
            targets: &[0, 1].map(|_| {
                Some(wgpu::ColorTargetState {
                    format: wgpu::TextureFormat::Rgba32Float,
                    blend: Some(wgpu::BlendState {
                        color: add,
                        alpha: add,
                    }),
                    write_mask: wgpu::ColorWrites::ALL,
                })
            }),
        }),
        multiview_mask: None,
        cache: None,
    })
}

impl Raster {
    pub(super) fn new(dev: &wgpu::Device, module: &wgpu::ShaderModule, camera: &Pinhole) -> Self {
        let layout = quad_layout(dev);
        Raster {
            pipeline: quad_pipeline(dev, module, &layout),
            layout,
            targets: [0, 1].map(|_| sums_texture(dev, camera.width(), camera.height(), true)),
            primaries: Grow::new(dev, "primary segments"),
            quads: Grow::new(dev, "beam quads"),
            reach: reach_per_radius(camera),
        }
    }
}

impl GpuBeams {
    /// Uploads the primary segments and the quads of the pass's beams when primaries are
    /// rasterised; returns the number of quads.
    pub(super) fn write_quads(&mut self, t: &TracedPass, segs: &SegmentUpload) -> Result<u32> {
        let Some(r) = &mut self.raster else {
            return Ok(0);
        };
        let (cam, radius, reach) = (&self.camera, t.beam_radius, r.reach);
        let (w, h) = (cam.width(), cam.height());
        let quads: Vec<BeamQuad> = t
            .beams
            .par_iter()
            .filter_map(|b| {
                let line = Line::project(cam, b, radius * b.scale, reach)?;
                Some(BeamQuad::new(line.rectangle(), b, w, h))
            })
            .collect();
        r.primaries
            .write(&self.gpu, bytemuck::cast_slice(&segs.primaries))?;
        r.quads.write(&self.gpu, bytemuck::cast_slice(&quads))?;
        Ok(quads.len() as u32)
    }

    /// Draws `count` beam quads into the cleared primary targets.
    pub(super) fn draw_quads(&self, r: &Raster, enc: &mut wgpu::CommandEncoder, count: u32) {
        let bind = bind_group(
            &self.gpu.device,
            &r.layout,
            &[
                (0, self.params_buf.as_entire_binding()),
                (4, self.tr_steps.buf.as_entire_binding()),
                (7, self.grid_buf.as_entire_binding()),
                (11, r.primaries.buf.as_entire_binding()),
                (12, r.quads.buf.as_entire_binding()),
                (13, self.octree_nodes.as_entire_binding()),
                (14, self.octrees.as_entire_binding()),
            ],
        );
        let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("beam quads"),
            color_attachments: &r.targets.each_ref().map(|view| {
                Some(wgpu::RenderPassColorAttachment {
                    view,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
                        store: wgpu::StoreOp::Store,
                    },
                })
            }),
            depth_stencil_attachment: None,
            timestamp_writes: None,
            occlusion_query_set: None,
            multiview_mask: None,
        });
        if count > 0 {
            pass.set_pipeline(&r.pipeline);
            pass.set_bind_group(0, &bind, &[]);
            pass.draw(0..6, 0..count);
        }
    }
}
