// One Adam step over every parameter of a resident model, one invocation per value: the
// CPU's `optim::Adam::step` (a learning rate per parameter group, found from the value's
// place in its Gaussian), with the gradients of the mean-opacity and mean-scale penalties
// added first. A non-finite
// gradient leaves its value and moments alone and raises bit 0 of `flags`; a non-finite value
// after the update raises bit 1 (the trainer stops on either, as on the CPU).

struct AdamStep {
    // Values in the model; values per Gaussian; mean-opacity penalty per Gaussian.
    n: u32,
    stride: u32,
    reg: f32,
    eps: f32,
    b1: f32,
    b2: f32,
    // Bias corrections 1 − βᵗ.
    bc1: f32,
    bc2: f32,
    // Means, log-scales, rotations, opacities.
    lr_a: vec4<f32>,
    // SH DC, SH rest; then the mean-scale penalty per value, and one unused.
    lr_b: vec4<f32>,
}

@group(0) @binding(0) var<uniform> st: AdamStep;
@group(0) @binding(1) var<storage, read_write> params: array<f32>;
@group(0) @binding(2) var<storage, read> grads: array<f32>;
@group(0) @binding(3) var<storage, read_write> m: array<f32>;
@group(0) @binding(4) var<storage, read_write> v: array<f32>;
@group(0) @binding(5) var<storage, read_write> flags: atomic<u32>;

@compute @workgroup_size(256)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    let i = linear_group(wid, nwg) * 256u + li;
    if (i >= st.n) {
        return;
    }
    let k = i % st.stride;
    var lr: f32;
    if (k < 3u) {
        lr = st.lr_a.x;
    } else if (k < 6u) {
        lr = st.lr_a.y;
    } else if (k < 10u) {
        lr = st.lr_a.z;
    } else if (k == 10u) {
        lr = st.lr_a.w;
    } else if (k < 14u) {
        lr = st.lr_b.x;
    } else {
        lr = st.lr_b.y;
    }
    var g = grads[i];
    if (k == 10u && st.reg > 0.0) {
        let o = 1.0 / (1.0 + exp(-params[i]));
        g = g + st.reg * o * (1.0 - o);
    }
    if (k >= 3u && k < 6u && st.lr_b.z > 0.0) {
        g = g + st.lr_b.z * exp(params[i]);
    }
    if (!finite(g)) {
        atomicOr(&flags, 1u);
        return;
    }
    let mi = st.b1 * m[i] + (1.0 - st.b1) * g;
    let vi = st.b2 * v[i] + (1.0 - st.b2) * g * g;
    m[i] = mi;
    v[i] = vi;
    let p = params[i] - lr * (mi / st.bc1) / (sqrt(vi / st.bc2) + st.eps);
    params[i] = p;
    if (!finite(p)) {
        atomicOr(&flags, 2u);
    }
}
