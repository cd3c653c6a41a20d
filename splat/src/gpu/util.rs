//! Small helpers over wgpu: buffers, bind groups, dispatch sizes, read-back.

use wgpu::util::DeviceExt;

use crate::error::SplatError;

/// Workgroups of 256 invocations needed for `n` items.
pub fn blocks(n: u32) -> u32 {
    n.div_ceil(256)
}

/// A dispatch of `groups` workgroups laid out in two dimensions (at most 65535 per dimension);
/// the shaders recover the linear index with `linear_group`.
pub fn grid(groups: u32) -> (u32, u32) {
    let x = groups.clamp(1, 65535);
    (x, groups.div_ceil(x).max(1))
}

pub fn storage(device: &wgpu::Device, label: &str, bytes: u64) -> wgpu::Buffer {
    device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        // Bindings must not be empty.
        size: bytes.max(4),
        usage: wgpu::BufferUsages::STORAGE
            | wgpu::BufferUsages::COPY_SRC
            | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    })
}

/// Working buffers kept from one training step to the next: the step's `k`-th request gets
/// slot `k` again, grown when it is too small. Every kernel writes (or the encoder clears)
/// what it later reads, so a buffer's old contents never matter.
#[derive(Default)]
pub struct Pool {
    slots: Vec<wgpu::Buffer>,
    next: usize,
    generation: u64,
}

impl Pool {
    /// Starts a step: every slot is free again, and what the last step handed out is stale.
    pub fn reset(&mut self) -> u64 {
        self.next = 0;
        self.generation += 1;
        self.generation
    }

    pub fn generation(&self) -> u64 {
        self.generation
    }

    /// Bytes held.
    pub fn bytes(&self) -> u64 {
        self.slots.iter().map(|b| b.size()).sum()
    }
}

/// The size of a pool slot asked for `bytes`: a quarter more, so sizes that change from step
/// to step (the number of tile keys) reallocate rarely, but never past the largest binding
/// `cap` when the request fits it, since a slot is bound whole.
pub fn pooled_size(bytes: u64, cap: u64) -> u64 {
    let roomy = (bytes + bytes / 4).next_multiple_of(256);
    if roomy <= cap {
        roomy
    } else {
        cap.max(bytes.max(4))
    }
}

/// Where a pass takes its working buffers from: fresh ones, or a [`Pool`].
pub struct Scratch<'p>(pub Option<&'p mut Pool>);

impl Scratch<'_> {
    pub fn fresh() -> Scratch<'static> {
        Scratch(None)
    }

    pub fn storage(&mut self, device: &wgpu::Device, label: &str, bytes: u64) -> wgpu::Buffer {
        let Some(pool) = self.0.as_deref_mut() else {
            return storage(device, label, bytes);
        };
        let k = pool.next;
        pool.next += 1;
        match pool.slots.get(k) {
            Some(b) if b.size() >= bytes.max(4) => b.clone(),
            _ => {
                let cap = device.limits().max_storage_buffer_binding_size;
                let b = storage(device, label, pooled_size(bytes, cap));
                if k < pool.slots.len() {
                    pool.slots[k] = b.clone();
                } else {
                    pool.slots.push(b.clone());
                }
                b
            }
        }
    }

    /// A working buffer holding `data`.
    pub fn storage_init(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        label: &str,
        data: &[u8],
    ) -> wgpu::Buffer {
        if self.0.is_none() {
            return storage_init(device, label, data);
        }
        let b = self.storage(device, label, data.len() as u64);
        if !data.is_empty() {
            queue.write_buffer(&b, 0, data);
        }
        b
    }
}

pub fn storage_init(device: &wgpu::Device, label: &str, data: &[u8]) -> wgpu::Buffer {
    let padded;
    let contents = if data.is_empty() {
        padded = [0u8; 4];
        &padded[..]
    } else {
        data
    };
    device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some(label),
        contents,
        usage: wgpu::BufferUsages::STORAGE
            | wgpu::BufferUsages::COPY_SRC
            | wgpu::BufferUsages::COPY_DST,
    })
}

pub fn uniform(device: &wgpu::Device, label: &str, data: &[u8]) -> wgpu::Buffer {
    device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some(label),
        contents: data,
        usage: wgpu::BufferUsages::UNIFORM,
    })
}

pub fn bind(
    device: &wgpu::Device,
    pipeline: &wgpu::ComputePipeline,
    buffers: &[&wgpu::Buffer],
) -> wgpu::BindGroup {
    let whole: Vec<_> = buffers.iter().map(|b| b.as_entire_binding()).collect();
    bind_resources(device, pipeline, whole)
}

/// `bytes` bytes of `buffer` from `offset` on, as one binding.
pub fn part(buffer: &wgpu::Buffer, offset: u64, bytes: u64) -> wgpu::BindingResource<'_> {
    wgpu::BindingResource::Buffer(wgpu::BufferBinding {
        buffer,
        offset,
        size: wgpu::BufferSize::new(bytes.max(4)),
    })
}

/// A bind group of whole buffers and [`part`]s, binding `i` the `i`-th.
pub fn bind_resources(
    device: &wgpu::Device,
    pipeline: &wgpu::ComputePipeline,
    resources: Vec<wgpu::BindingResource<'_>>,
) -> wgpu::BindGroup {
    let entries: Vec<wgpu::BindGroupEntry> = resources
        .into_iter()
        .enumerate()
        .map(|(i, resource)| wgpu::BindGroupEntry {
            binding: i as u32,
            resource,
        })
        .collect();
    device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: None,
        layout: &pipeline.get_bind_group_layout(0),
        entries: &entries,
    })
}

/// Records one dispatch of `groups` workgroups (laid out by [`grid`]).
pub fn dispatch(
    encoder: &mut wgpu::CommandEncoder,
    pipeline: &wgpu::ComputePipeline,
    group: &wgpu::BindGroup,
    (x, y): (u32, u32),
) {
    let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor::default());
    pass.set_pipeline(pipeline);
    pass.set_bind_group(0, group, &[]);
    pass.dispatch_workgroups(x, y, 1);
}

/// Copies `bytes` from `offset` of each source into one mappable buffer, submits, waits and
/// returns them.
pub fn read_back(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    mut encoder: wgpu::CommandEncoder,
    sources: &[(&wgpu::Buffer, u64, u64)],
) -> Result<Vec<Vec<u8>>, SplatError> {
    let total: u64 = sources.iter().map(|(_, _, n)| n.next_multiple_of(4)).sum();
    let staging = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("read back"),
        size: total.max(4),
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let mut at = 0;
    for (b, offset, n) in sources {
        if *n > 0 {
            encoder.copy_buffer_to_buffer(b, *offset, &staging, at, *n);
        }
        at += n.next_multiple_of(4);
    }
    queue.submit([encoder.finish()]);
    let slice = staging.slice(..);
    let (tx, rx) = std::sync::mpsc::channel();
    slice.map_async(wgpu::MapMode::Read, move |r| {
        let _ = tx.send(r);
    });
    device
        .poll(wgpu::PollType::wait_indefinitely())
        .map_err(|e| SplatError::Gpu(format!("waiting for the GPU: {e}")))?;
    rx.recv()
        .map_err(|e| SplatError::Gpu(format!("read-back lost: {e}")))?
        .map_err(|e| SplatError::Gpu(format!("cannot read GPU memory back: {e}")))?;
    let view = slice
        .get_mapped_range()
        .map_err(|e| SplatError::Gpu(format!("cannot read GPU memory back: {e}")))?;
    let mut out = Vec::with_capacity(sources.len());
    let mut at = 0usize;
    for (_, _, n) in sources {
        out.push(view[at..at + *n as usize].to_vec());
        at += n.next_multiple_of(4) as usize;
    }
    drop(view);
    staging.unmap();
    Ok(out)
}

pub fn u32s(bytes: &[u8]) -> Vec<u32> {
    bytemuck::pod_collect_to_vec(bytes)
}

pub fn f32s(bytes: &[u8]) -> Vec<f32> {
    bytemuck::pod_collect_to_vec(bytes)
}

#[cfg(test)]
mod tests {
    use super::pooled_size;

    #[test]
    fn a_pool_slot_has_room_to_grow_but_stays_bindable() {
        let cap = 1 << 27;
        assert_eq!(pooled_size(1000, cap), 1280);
        assert!(pooled_size(1000, cap) >= 1000);
        // A request that fits one binding gets a slot that still fits it.
        let near = cap - (cap >> 4);
        assert_eq!(pooled_size(near, cap), cap);
        assert_eq!(pooled_size(cap, cap), cap);
        // One bound only in pieces (the parameters' gradients) gets what it asked for.
        assert_eq!(pooled_size(cap + 4, cap), cap + 4);
    }
}
