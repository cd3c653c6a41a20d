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
