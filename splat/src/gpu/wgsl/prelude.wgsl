// Shared by every stage. The constants above this line are generated from
// `splat::conventions`, so the GPU and the CPU use the same numbers.

const PROJ_STRIDE: u32 = 12u;

struct Camera {
    // Rows of the world-to-camera rotation.
    r0: vec4<f32>,
    r1: vec4<f32>,
    r2: vec4<f32>,
    // Translation; w: near.
    t: vec4<f32>,
    // fx, fy, cx, cy.
    intr: vec4<f32>,
    // Jacobian clamp limits of x/z and y/z: neg_x, pos_x, neg_y, pos_y.
    lim: vec4<f32>,
    // Camera centre; w: far.
    pos: vec4<f32>,
    // Background colour.
    bg: vec4<f32>,
    // width, height, tiles_x, tiles_y.
    dims: vec4<u32>,
    // Gaussians, SH degree rendered, parameters per Gaussian, antialiased.
    cfg: vec4<u32>,
}

// The Gaussians one dispatch handles: the parameter buffers are bound from Gaussian `first`
// on, so a scene larger than the device binds in one buffer is projected in pieces.
struct Chunk {
    first: u32,
    count: u32,
}

// The element count of a one-dimensional pass.
struct Len {
    n: u32,
}

// One digit pass of the radix sort.
struct SortPass {
    n: u32,
    shift: u32,
    use_hi: u32,
    num_blocks: u32,
}

// Dispatches of more than 65535 workgroups are laid out in two dimensions.
fn linear_group(wid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return wid.y * nwg.x + wid.x;
}

fn finite(x: f32) -> bool {
    return x == x && abs(x) <= 3.40282347e38;
}

fn finite3(v: vec3<f32>) -> bool {
    return finite(v.x) && finite(v.y) && finite(v.z);
}

// Tiles [x0, x1) × [y0, y1) touched by a footprint (gsplat's rule, as `tiles::tile_rect`).
fn tile_rect(m: vec2<f32>, r: vec2<f32>, tiles_x: u32, tiles_y: u32) -> vec4<u32> {
    if (r.x <= 0.0 && r.y <= 0.0) {
        return vec4<u32>(0u);
    }
    let ts = f32(TILE_SIZE);
    let tx = f32(tiles_x);
    let ty = f32(tiles_y);
    return vec4<u32>(
        u32(clamp(floor((m.x - r.x) / ts), 0.0, tx)),
        u32(clamp(ceil((m.x + r.x) / ts), 0.0, tx)),
        u32(clamp(floor((m.y - r.y) / ts), 0.0, ty)),
        u32(clamp(ceil((m.y + r.y) / ts), 0.0, ty)),
    );
}

// The SH basis at unit direction `d` up to `deg` (`sh::basis`); higher entries are zero.
fn sh_basis(deg: u32, d: vec3<f32>) -> array<f32, 16> {
    var b: array<f32, 16>;
    b[0] = SH_C0;
    let x = d.x;
    let y = d.y;
    let z = d.z;
    if (deg >= 1u) {
        b[1] = -SH_C1 * y;
        b[2] = SH_C1 * z;
        b[3] = -SH_C1 * x;
    }
    if (deg >= 2u) {
        let xx = x * x;
        let yy = y * y;
        let zz = z * z;
        b[4] = SH_C2_XY * x * y;
        b[5] = -SH_C2_XY * y * z;
        b[6] = SH_C2_ZZ * zz - SH_C2_ZZ0;
        b[7] = -SH_C2_XY * x * z;
        b[8] = SH_C2_XX * (xx - yy);
        if (deg >= 3u) {
            let a = SH_C3_C * zz + SH_C3_C0;
            b[9] = SH_C3_A * (3.0 * xx * y - yy * y);
            b[10] = SH_C3_B * z * 2.0 * x * y;
            b[11] = a * y;
            b[12] = z * (SH_C3_D * zz - SH_C3_D0);
            b[13] = a * x;
            b[14] = SH_C3_B * z * (xx - yy);
            b[15] = SH_C3_A * (xx * x - 3.0 * x * yy);
        }
    }
    return b;
}

// A quaternion's rotation (`project::quat_to_rotmat`).
struct QuatRot {
    rot: mat3x3<f32>,
    // The normalised quaternion (w, x, y, z).
    qn: vec4<f32>,
    // Its length; 0 for the zero (or a non-finite) quaternion, whose rotation is the identity.
    len: f32,
}

// Scaled by the largest component first, so huge quaternions do not overflow.
fn quat_rot(q: vec4<f32>) -> QuatRot {
    var out = QuatRot(
        mat3x3<f32>(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0),
        vec4<f32>(1.0, 0.0, 0.0, 0.0),
        0.0,
    );
    let m = max(max(abs(q.x), abs(q.y)), max(abs(q.z), abs(q.w)));
    if (finite(m) && m > 0.0) {
        let s = q / m;
        let len_s = sqrt(dot(s, s));
        let qn = s / len_s;
        out.qn = qn;
        out.len = m * len_s;
        let w = qn.x;
        let x = qn.y;
        let y = qn.z;
        let z = qn.w;
        out.rot = mat3x3<f32>(
            1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z), 2.0 * (x * z - w * y),
            2.0 * (x * y - w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z + w * x),
            2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y),
        );
    }
    return out;
}

// What the projection and its backward share for one Gaussian (`project::geometry`): camera-space
// mean, rotation, scale, the EWA Jacobian at the clamped point and the screen covariance before
// the low-pass. `valid` is false when the Gaussian is culled before its footprint exists.
struct Geometry {
    valid: bool,
    p_cam: vec3<f32>,
    q: QuatRot,
    scale: vec3<f32>,
    // R diag(scale).
    mm: mat3x3<f32>,
    cov_cam: mat3x3<f32>,
    j0: vec3<f32>,
    j1: vec3<f32>,
    // The clamped x/z and y/z at which the Jacobian is taken, and whether each clamped.
    txy: vec2<f32>,
    clamped_x: bool,
    clamped_y: bool,
    // (a, b, c) of [[a, b], [b, c]].
    cov: vec3<f32>,
}

fn geometry(cam: Camera, mean: vec3<f32>, log_scale: vec3<f32>, quat: vec4<f32>) -> Geometry {
    var g: Geometry;
    g.valid = false;
    g.p_cam = vec3<f32>(dot(cam.r0.xyz, mean), dot(cam.r1.xyz, mean), dot(cam.r2.xyz, mean))
        + cam.t.xyz;
    let z = g.p_cam.z;
    if (!(finite3(g.p_cam) && z >= cam.t.w && z <= cam.pos.w)) {
        return g;
    }
    g.q = quat_rot(quat);
    let rot = g.q.rot;
    g.scale = exp(log_scale);
    g.mm = mat3x3<f32>(rot[0] * g.scale.x, rot[1] * g.scale.y, rot[2] * g.scale.z);
    let wr = transpose(mat3x3<f32>(cam.r0.xyz, cam.r1.xyz, cam.r2.xyz));
    g.cov_cam = wr * (g.mm * transpose(g.mm)) * transpose(wr);
    let rx = g.p_cam.x / z;
    let ry = g.p_cam.y / z;
    let cx = clamp(rx, -cam.lim.x, cam.lim.y);
    let cy = clamp(ry, -cam.lim.z, cam.lim.w);
    g.clamped_x = cx != rx;
    g.clamped_y = cy != ry;
    g.txy = vec2<f32>(z * cx, z * cy);
    let rz = 1.0 / z;
    let rz2 = rz * rz;
    g.j0 = vec3<f32>(cam.intr.x * rz, 0.0, -cam.intr.x * g.txy.x * rz2);
    g.j1 = vec3<f32>(0.0, cam.intr.y * rz, -cam.intr.y * g.txy.y * rz2);
    let s0 = g.cov_cam * g.j0;
    let s1 = g.cov_cam * g.j1;
    g.cov = vec3<f32>(dot(g.j0, s0), dot(g.j0, s1), dot(g.j1, s1));
    g.valid = finite3(g.cov);
    return g;
}
