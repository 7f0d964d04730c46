//! Buffers both kernels use: created, filled, bound and read back one way. Their Pod
//! contents are defined in [`super::layout`].
use wgpu::util::DeviceExt;

use super::Gpu;
use crate::error::{Error, Result};

/// Segments or pixels per dispatch: long single dispatches can lose the device.
pub const CHUNK: u32 = 65536;
pub(crate) const READ: wgpu::BufferBindingType =
    wgpu::BufferBindingType::Storage { read_only: true };
pub(crate) const READ_WRITE: wgpu::BufferBindingType =
    wgpu::BufferBindingType::Storage { read_only: false };
pub(crate) const UNIFORM: wgpu::BufferBindingType = wgpu::BufferBindingType::Uniform;

/// Copies `size` bytes of `src` to the CPU at the end of `enc`'s commands, submits them and
/// waits; `what` names the data in errors.
pub(crate) fn read_back<T: bytemuck::Pod>(
    gpu: &Gpu,
    mut enc: wgpu::CommandEncoder,
    src: &wgpu::Buffer,
    size: u64,
    what: &str,
) -> Result<Vec<T>> {
    let staging = gpu.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(what),
        size,
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    enc.copy_buffer_to_buffer(src, 0, &staging, 0, size);
    gpu.queue.submit([enc.finish()]);
    let slice = staging.slice(..);
    let (tx, rx) = std::sync::mpsc::channel();
    slice.map_async(wgpu::MapMode::Read, move |r| {
        let _ = tx.send(r);
    });
    gpu.device
        .poll(wgpu::PollType::wait_indefinitely())
        .map_err(|e| Error::Gpu(format!("waiting for {what}: {e}")))?;
    rx.recv()
        .map_err(|_| Error::Gpu(format!("reading {what} never completed")))?
        .map_err(|e| Error::Gpu(format!("mapping {what}: {e}")))?;
    let view = slice
        .get_mapped_range()
        .map_err(|e| Error::Gpu(format!("reading {what}: {e}")))?;
    let data = bytemuck::cast_slice::<u8, T>(&view).to_vec();
    drop(view);
    staging.unmap();
    Ok(data)
}

/// Bytes between entries of a uniform table of `T` read with dynamic offsets.
pub(crate) fn uniform_stride<T>(gpu: &Gpu) -> u64 {
    (gpu.limits.min_uniform_buffer_offset_alignment as u64).max(std::mem::size_of::<T>() as u64)
}

/// `items` laid out `stride` bytes apart, for a uniform read with dynamic offsets.
pub(crate) fn uniform_table<'a, T: bytemuck::Pod>(
    items: impl IntoIterator<Item = &'a T>,
    stride: u64,
) -> Vec<u8> {
    items
        .into_iter()
        .flat_map(|item| {
            let mut b = bytemuck::bytes_of(item).to_vec();
            b.resize(stride as usize, 0);
            b
        })
        .collect()
}

/// A buffer binding of a bind group layout, seen by `stages`.
pub(crate) fn buffer_entry(
    binding: u32,
    stages: wgpu::ShaderStages,
    ty: wgpu::BufferBindingType,
    dynamic_offset: bool,
) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: stages,
        ty: wgpu::BindingType::Buffer {
            ty,
            has_dynamic_offset: dynamic_offset,
            min_binding_size: None,
        },
        count: None,
    }
}

/// A read-only storage buffer holding `data` (16 zero bytes if empty: no binding may be).
/// A storage buffer holding `data` (16 zero bytes when empty: a binding may not be).
pub(crate) fn storage_init(gpu: &Gpu, label: &str, data: &[u8]) -> Result<wgpu::Buffer> {
    if data.len() as u64 > gpu.limits.max_storage_buffer_binding_size {
        return Err(Error::Gpu(format!(
            "{label} needs {} bytes, over the adapter's storage binding limit of {}",
            data.len(),
            gpu.limits.max_storage_buffer_binding_size
        )));
    }
    let contents: &[u8] = if data.is_empty() { &[0; 16] } else { data };
    Ok(gpu
        .device
        .create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(label),
            contents,
            usage: wgpu::BufferUsages::STORAGE,
        }))
}

pub(crate) fn storage(dev: &wgpu::Device, label: &str, size: u64) -> wgpu::Buffer {
    dev.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size,
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    })
}

pub(crate) fn bind_group(
    dev: &wgpu::Device,
    layout: &wgpu::BindGroupLayout,
    resources: &[(u32, wgpu::BindingResource)],
) -> wgpu::BindGroup {
    let entries: Vec<wgpu::BindGroupEntry> = resources
        .iter()
        .map(|(binding, resource)| wgpu::BindGroupEntry {
            binding: *binding,
            resource: resource.clone(),
        })
        .collect();
    dev.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("beam estimate"),
        layout,
        entries: &entries,
    })
}

/// A storage buffer that grows to fit.
pub(crate) struct Grow {
    label: &'static str,
    pub(crate) buf: wgpu::Buffer,
}

impl Grow {
    pub(crate) fn new(dev: &wgpu::Device, label: &'static str) -> Self {
        Grow {
            label,
            buf: storage(dev, label, 256),
        }
    }

    pub(crate) fn write(&mut self, gpu: &Gpu, data: &[u8]) -> Result<()> {
        self.reserve(gpu, data.len() as u64)?;
        if !data.is_empty() {
            gpu.queue.write_buffer(&self.buf, 0, data);
        }
        Ok(())
    }

    /// Makes room for `bytes` (contents undefined).
    pub(crate) fn reserve(&mut self, gpu: &Gpu, bytes: u64) -> Result<()> {
        let need = bytes.max(16);
        if need > gpu.limits.max_storage_buffer_binding_size {
            return Err(Error::Gpu(format!(
                "{} needs {need} bytes, over the adapter's storage binding limit of {} \
                 (use a smaller image or --device cpu)",
                self.label, gpu.limits.max_storage_buffer_binding_size
            )));
        }
        if need > self.buf.size() {
            self.buf = storage(&gpu.device, self.label, need.next_power_of_two());
        }
        Ok(())
    }
}
