// RESEARCH PROTOTYPE (bench/simd_paths_probe.py): SIMD_WIDTH paths per work-item, one path a
// vector lane (structure of arrays, a mask of the paths still running), against the megakernel
// (integrator.cl), which runs one path per work-item with scalar path state.
//
// Scope: what mitsuba-cbox needs and nothing more: quads only, tested by brute force one quad
// at a time against all lanes (in QuadBlock order, so that ties go to the same quad as
// Scene_Intersect's; a block is skipped when no running lane meets its bounding box); diffuse
// materials; exactly one emitter, a quad; NEE + MIS as Integrator_Li does at diffuse vertices;
// no Russian roulette; the independent sampler. Every operation mirrors the megakernel's,
// expression for expression (OpenCL C contracts a * b + c into an fma within one expression
// only), so a sample's radiance should equal the megakernel's to the bit: the same Philox
// numbers (rng.h, one uint vector a word of the counter), the same hits, the same float
// operations. Left out: the rare-case fallbacks of Length3/Normalize3 (tiny or huge vectors).
//
// The host checks what the kernel assumes (bench/simd_paths_probe.py): one emitter, a quad;
// diffuse materials; no spheres, triangles or BVH.
//
// Builtins PoCL may not inline (pip PoCL 3.0 calls sqrt(float16): see vecmath.h) are replaced
// by x86 builtins or bit operations with the same results.
#include "launch.h"
#include "rng.h"
#include "scene_types.h"
#include "vecmath.h"

#ifdef SIMD_NO_MIN_VECTOR_WIDTH // the experiment: --define SIMD_NO_MIN_VECTOR_WIDTH
#define SIMD_ATTR
#endif
#include "sampler_lanes.h" // V_Uniform4Lanes (its lanes at different dimensions)
#include "simd_lanes.h"

#define SURFACE_ERROR_SCALE (32.0f * FLT_EPSILON)

// Lane statistics (bench/simd_paths_probe.py): counters[COUNTER_*]
#define COUNTER_NONFINITE 0
#define COUNTER_RAYS 1
#define COUNTER_BOUNCE_STEPS 2  // bounce-loop iterations, summed over work-items
#define COUNTER_BOUNCE_LANES 3  // running lanes at the start of each iteration, summed
#define COUNTER_SHADOW_STEPS 4  // iterations that traced shadow rays
#define COUNTER_SHADOW_LANES 5  // lanes tracing a shadow ray in those, summed
#define COUNTER_LAST_GROUP 6    // 1 + the highest work-group id that traced a sample
#define COUNTER_NEXT_CHUNK 7    // simd_paths_regen, SIMD_LAYOUT_QUEUE: the next chunk to take
#define COUNTER_COUNT 8

// Copysign(1.0f, y)
SIMD_FN vfloat V_SignOf(vfloat y)
{
    return AS_VFLOAT((AS_VUINT(y) & 0x80000000u) | 0x3f800000u);
}

// ----------------------------------------------------------------------------- geometry

// The slab test of Bounds_Hit on lanes: where each lane's ray can meet the box before tmax.
SIMD_FN vint V_BoundsHit(__global const float *lower, __global const float *upper, vfloat ox,
                         vfloat oy, vfloat oz, vfloat ix, vfloat iy, vfloat iz, vfloat tmax)
{
    vfloat t0x = (lower[0] - ox) * ix;
    vfloat t0y = (lower[1] - oy) * iy;
    vfloat t0z = (lower[2] - oz) * iz;
    vfloat t1x = (upper[0] - ox) * ix;
    vfloat t1y = (upper[1] - oy) * iy;
    vfloat t1z = (upper[2] - oz) * iz;
    vfloat nx = t0x < t1x ? t0x : t1x;
    vfloat ny = t0y < t1y ? t0y : t1y;
    vfloat nz = t0z < t1z ? t0z : t1z;
    vfloat fx = t0x < t1x ? t1x : t0x;
    vfloat fy = t0y < t1y ? t1y : t0y;
    vfloat fz = t0z < t1z ? t1z : t0z;
    vfloat t_enter = nx > ny ? nx : ny;
    t_enter = t_enter > nz ? t_enter : nz;
    vfloat t_exit = fx < fy ? fx : fy;
    t_exit = t_exit < fz ? t_exit : fz;
    return !((t_enter > t_exit) | (t_exit < 0.0f) | (t_enter > tmax));
}

// Hit mask of lane j of a QuadBlock (QuadBlock_Hits' operations, one quad against all lanes)
// before tmax, its distances in *t_out.
SIMD_FN vint V_QuadHits(__global const QuadBlock *block, int j, vfloat ox, vfloat oy, vfloat oz,
                        vfloat dx, vfloat dy, vfloat dz, vfloat tmax, vfloat *t_out)
{
    float nx = block->normal[0][j];
    float ny = block->normal[1][j];
    float nz = block->normal[2][j];
    vfloat t = (block->plane_d[j] - (nx * ox + ny * oy + nz * oz)) / (nx * dx + ny * dy + nz * dz);
    vfloat rx = ox + t * dx - block->corner[0][j];
    vfloat ry = oy + t * dy - block->corner[1][j];
    vfloat rz = oz + t * dz - block->corner[2][j];
    vfloat a = rx * block->u_dual[0][j] + ry * block->u_dual[1][j] + rz * block->u_dual[2][j];
    vfloat b = rx * block->v_dual[0][j] + ry * block->v_dual[1][j] + rz * block->v_dual[2][j];
    *t_out = t;
    return (t > 0.0f) & (t < tmax) & (a >= 0.0f) & (a <= 1.0f) & (b >= 0.0f) & (b <= 1.0f);
}

// The closest quad along each running lane's ray: its distance (INFINITY if none), its index
// in *prim (-1 if none). Scene_Intersect's result: the first quad (block order) at the least t.
SIMD_FN vfloat V_Intersect(__global const QuadBlock *blocks, uint block_count, vint running,
                           vfloat ox, vfloat oy, vfloat oz, vfloat dx, vfloat dy, vfloat dz,
                           vint *prim)
{
    vfloat t = (vfloat)(INFINITY);
    vint id = (vint)(-1);
    vfloat ix = 1.0f / dx;
    vfloat iy = 1.0f / dy;
    vfloat iz = 1.0f / dz;
    for (uint b = 0; b < block_count; ++b) {
        __global const QuadBlock *block = &blocks[b];
        if (block->lower[3] == 0.0f &&
            V_Bits(running & V_BoundsHit(block->lower, block->upper, ox, oy, oz, ix, iy, iz,
                                         t)) == 0u)
            continue;
        for (int j = 0; j < QUAD_BLOCK_WIDTH; ++j) {
            int q = block->quad[j];
            if (q < 0)
                continue;
            vfloat tq;
            vint hit = V_QuadHits(block, j, ox, oy, oz, dx, dy, dz, t, &tq);
            t = hit ? tq : t;
            id = hit ? (vint)q : id;
        }
    }
    *prim = id;
    return t;
}

// Where some quad lies along the lanes' rays before tmax, for the lanes of `tested` (the
// others' answers are meaningless); stops when every tested lane is blocked.
SIMD_FN vint V_Occluded(__global const QuadBlock *blocks, uint block_count, vint tested,
                        vfloat ox, vfloat oy, vfloat oz, vfloat dx, vfloat dy, vfloat dz,
                        vfloat tmax)
{
    vint blocked = (vint)0;
    vfloat ix = 1.0f / dx;
    vfloat iy = 1.0f / dy;
    vfloat iz = 1.0f / dz;
    for (uint b = block_count; b-- > 0u;) {
        __global const QuadBlock *block = &blocks[b];
        vint open = tested & ~blocked;
        if (block->lower[3] == 0.0f &&
            V_Bits(open & V_BoundsHit(block->lower, block->upper, ox, oy, oz, ix, iy, iz,
                                      tmax)) == 0u)
            continue;
        for (int j = 0; j < QUAD_BLOCK_WIDTH; ++j) {
            if (block->quad[j] < 0)
                continue;
            vfloat tq;
            blocked |= V_QuadHits(block, j, ox, oy, oz, dx, dy, dz, tmax, &tq);
        }
        if (V_Bits(tested & ~blocked) == 0u)
            break;
    }
    return blocked;
}

// ----------------------------------------------------------------------------- path steps

// What every lane shares: the scene (quads only, one quad emitter) and the launch's settings.
typedef struct {
    __global const Quad *quads;
    __global const QuadBlock *quad_blocks;
    uint quad_block_count;
    __global const Material *materials;
    __global const Emitter *emitter; // the one emitter
    __global const Quad *light;      // its quad
    uint seed;
    int max_depth;
} PathScene;

// SIMD_WIDTH paths, one a lane: ray, radiance, throughput, the pdf of the last BSDF sample,
// depth, the sample's Philox stream (pixel, sample, redraw), and whether the path runs on.
typedef struct {
    vfloat ox, oy, oz, dx, dy, dz;
    vfloat L_r, L_g, L_b;
    vfloat beta_r, beta_g, beta_b;
    vfloat prev_pdfW;
    vint depth;
    vuint pixel, sample, redraw;
    vint running;
} Paths;

// Lane statistics, summed into counters[COUNTER_*] at the end.
typedef struct {
    uint rays, bounce_steps, bounce_lanes, shadow_steps, shadow_lanes;
} LaneStats;

// Camera rays through the lanes' samples (Camera_Direction: pixel index, position in it).
SIMD_FN void V_CameraRays(__global const Camera *camera, uint image_width, uint image_height,
                          vuint pixel, vfloat pos_x, vfloat pos_y, vfloat *dx, vfloat *dy,
                          vfloat *dz)
{
    vfloat image_x = TO_VFLOAT(pixel % image_width) + 0.5f + pos_x;
    vfloat image_y = TO_VFLOAT(pixel / image_width) + 0.5f + pos_y;
    vfloat sx = 2.0f * image_x / (float)image_width - 1.0f;
    vfloat sy = 1.0f - 2.0f * image_y / (float)image_height;
    vfloat x = camera->forward[0] + sx * camera->right[0] + sy * camera->up[0];
    vfloat y = camera->forward[1] + sx * camera->right[1] + sy * camera->up[1];
    vfloat z = camera->forward[2] + sx * camera->right[2] + sy * camera->up[2];
    vfloat inv = 1.0f / V_Sqrt(V_Dot3(x, y, z, x, y, z));
    *dx = x * inv;
    *dy = y * inv;
    *dz = z * inv;
}

// One vertex of every running path (Integrator_Li's loop body): find the closest surface,
// add its emission, end the path there or sample direct light and the BSDF's next direction.
// Lanes whose path ends have running cleared; the others have their next ray.
SIMD_FN void V_PathStep(const PathScene *scene, Paths *paths, LaneStats *stats)
{
    uint running_bits = V_Bits(paths->running);
    stats->bounce_steps += 1u;
    stats->bounce_lanes += __builtin_popcount(running_bits);
    stats->rays += __builtin_popcount(running_bits);
    vfloat ox = paths->ox, oy = paths->oy, oz = paths->oz;
    vfloat dx = paths->dx, dy = paths->dy, dz = paths->dz;
    vint depth = paths->depth;
    vint running = paths->running;

    // Find the closest surface along the rays
    vint prim;
    vfloat t = V_Intersect(scene->quad_blocks, scene->quad_block_count, running, ox, oy, oz, dx,
                           dy, dz, &prim);
    running &= prim >= 0;

    // The hit quads' records (Scene_Surface), gathered lane by lane
    union {
        vfloat v;
        float s[SIMD_WIDTH];
    } ng_x, ng_y, ng_z, corner_abs, albedo_r, albedo_g, albedo_b;
    union {
        vint v;
        int s[SIMD_WIDTH];
    } material, emitting, two_sided, prims;
    prims.v = prim;
    for (int j = 0; j < SIMD_WIDTH; ++j) {
        __global const Quad *q = &scene->quads[prims.s[j] > 0 ? prims.s[j] : 0];
        ng_x.s[j] = q->normal[0];
        ng_y.s[j] = q->normal[1];
        ng_z.s[j] = q->normal[2];
        corner_abs.s[j] =
            Fmax(Fabs(q->corner[0]), Fmax(Fabs(q->corner[1]), Fabs(q->corner[2])));
        material.s[j] = q->material;
        emitting.s[j] = q->emitter;
        __global const Material *m = &scene->materials[q->material > 0 ? q->material : 0];
        albedo_r.s[j] = m->albedo[0];
        albedo_g.s[j] = m->albedo[1];
        albedo_b.s[j] = m->albedo[2];
        two_sided.s[j] = m->two_sided;
    }
    vfloat p_x = ox + t * dx;
    vfloat p_y = oy + t * dy;
    vfloat p_z = oz + t * dz;
    vfloat magnitude = V_MaxAbs3(ox, oy, oz) + t * V_MaxAbs3(dx, dy, dz) + corner_abs.v;
    vfloat error = SURFACE_ERROR_SCALE * magnitude;
    vfloat wo_x = -dx, wo_y = -dy, wo_z = -dz;
    vfloat cos_o = V_Dot3(ng_x.v, ng_y.v, ng_z.v, wo_x, wo_y, wo_z);

    // Add emission found by the rays, MIS-weighted unless they came from the camera
    __global const Emitter *emitter = scene->emitter;
    float Le_r = emitter->radiance[0];
    float Le_g = emitter->radiance[1];
    float Le_b = emitter->radiance[2];
    vfloat L_r = paths->L_r, L_g = paths->L_g, L_b = paths->L_b;
    vfloat beta_r = paths->beta_r, beta_g = paths->beta_g, beta_b = paths->beta_b;
    vint emitted = running & (emitting.v >= 0) & (cos_o > 0.0f);
    if (V_Bits(emitted) != 0u) {
        // Light_PdfW, then the power heuristic
        vfloat light_pdfW = emitter->pick_pdf * t * t / (cos_o * emitter->area);
        vfloat a2 = paths->prev_pdfW * paths->prev_pdfW;
        vfloat mis = a2 / (a2 + light_pdfW * light_pdfW);
        vint camera_ray = depth == 0;
        L_r = emitted ? (camera_ray ? L_r + beta_r * Le_r : L_r + beta_r * Le_r * mis) : L_r;
        L_g = emitted ? (camera_ray ? L_g + beta_g * Le_g : L_g + beta_g * Le_g * mis) : L_g;
        L_b = emitted ? (camera_ray ? L_b + beta_b * Le_b : L_b + beta_b * Le_b * mis) : L_b;
    }

    // End paths at the maximum depth, on surfaces that only emit, and one-sided surfaces
    // seen from behind
    running &= (depth != scene->max_depth) & (material.v >= 0);
    vint back = cos_o < 0.0f;
    running &= ~back | (two_sided.v != 0);
    paths->L_r = L_r;
    paths->L_g = L_g;
    paths->L_b = L_b;
    paths->running = running;
    if (V_Bits(running) == 0u)
        return;
    vfloat n_x = back ? -ng_x.v : ng_x.v;
    vfloat n_y = back ? -ng_y.v : ng_y.v;
    vfloat n_z = back ? -ng_z.v : ng_z.v;

    // Shading frame (Frame_FromNormal) and wo in it
    vfloat sign = V_SignOf(n_z);
    vfloat fa = -1.0f / (sign + n_z);
    vfloat fb = n_x * n_y * fa;
    vfloat s_x = 1.0f + sign * n_x * n_x * fa;
    vfloat s_y = sign * fb;
    vfloat s_z = -sign * n_x;
    vfloat t_x = fb;
    vfloat t_y = sign + n_y * n_y * fa;
    vfloat t_z = -n_y;
    vfloat wo_lz = V_Dot3(wo_x, wo_y, wo_z, n_x, n_y, n_z);

    // The vertex's random numbers (Sampler_Bounce, independent sampler: dimensions 1 + 2 depth
    // and 2 + 2 depth)
    vfloat u_light0, u_light1, u_light2, u_light3, u_bsdf0, u_bsdf1, u_bsdf2, u_bsdf3;
    vuint dim = TO_VUINT(depth) * 2u + 1u;
    V_Uniform4Lanes(scene->seed, paths->pixel, paths->sample, dim, paths->redraw, &u_light0,
                    &u_light1, &u_light2, &u_light3);
    V_Uniform4Lanes(scene->seed, paths->pixel, paths->sample, dim + 1u, paths->redraw, &u_bsdf0,
                    &u_bsdf1, &u_bsdf2, &u_bsdf3);

    // Sample direct illumination from the emitter (Light_SampleLi on a quad, then
    // Integrator_SampleDirect)
    {
        __global const Quad *light = scene->light;
        vfloat y_x = light->corner[0] + u_light1 * light->edge1[0] + u_light2 * light->edge2[0];
        vfloat y_y = light->corner[1] + u_light1 * light->edge1[1] + u_light2 * light->edge2[1];
        vfloat y_z = light->corner[2] + u_light1 * light->edge1[2] + u_light2 * light->edge2[2];
        vfloat to_x = y_x - p_x;
        vfloat to_y = y_y - p_y;
        vfloat to_z = y_z - p_z;
        vfloat dist = V_Sqrt(V_Dot3(to_x, to_y, to_z, to_x, to_y, to_z));
        vfloat wi_x = to_x / dist;
        vfloat wi_y = to_y / dist;
        vfloat wi_z = to_z / dist;
        vfloat cos_light =
            -V_Dot3(light->normal[0], light->normal[1], light->normal[2], wi_x, wi_y, wi_z);
        vfloat light_pdfW = emitter->pick_pdf * dist * dist / (cos_light * emitter->area);
        vint lit = running & (cos_light > 0.0f) & (light_pdfW > 0.0f);
        vfloat wi_lz = V_Dot3(wi_x, wi_y, wi_z, n_x, n_y, n_z);
        vint same_side = (wo_lz > 0.0f) & (wi_lz > 0.0f);
        vfloat cos_i = V_Fabs(wi_lz);
        vfloat f_r = (same_side ? albedo_r.v * M_1_PI_F : 0.0f) * cos_i;
        vfloat f_g = (same_side ? albedo_g.v * M_1_PI_F : 0.0f) * cos_i;
        vfloat f_b = (same_side ? albedo_b.v * M_1_PI_F : 0.0f) * cos_i;
        lit &= (f_r > 0.0f) | (f_g > 0.0f) | (f_b > 0.0f);
        uint lit_bits = V_Bits(lit);
        if (lit_bits != 0u) {
            // The shadow ray stops short of the emitter by both points' rounding bounds
            vfloat side =
                V_Dot3(wi_x, wi_y, wi_z, ng_x.v, ng_y.v, ng_z.v) > 0.0f ? error : -error;
            vfloat so_x = p_x + side * ng_x.v;
            vfloat so_y = p_y + side * ng_y.v;
            vfloat so_z = p_z + side * ng_z.v;
            vfloat light_error = SURFACE_ERROR_SCALE * V_MaxAbs3(p_x + dist * wi_x,
                                                                 p_y + dist * wi_y,
                                                                 p_z + dist * wi_z);
            vfloat tmax = dist - 2.0f * (error + light_error);
            stats->rays += __builtin_popcount(lit_bits);
            stats->shadow_steps += 1u;
            stats->shadow_lanes += __builtin_popcount(lit_bits);
            lit &= ~V_Occluded(scene->quad_blocks, scene->quad_block_count, lit, so_x, so_y, so_z,
                               wi_x, wi_y, wi_z, tmax);
            vfloat bsdf_pdfW = same_side ? wi_lz * M_1_PI_F : 0.0f;
            vfloat a2 = light_pdfW * light_pdfW;
            vfloat weight = a2 / (a2 + bsdf_pdfW * bsdf_pdfW);
            vfloat scale = weight / light_pdfW;
            vfloat d_r = f_r * Le_r * scale;
            vfloat d_g = f_g * Le_g * scale;
            vfloat d_b = f_b * Le_b * scale;
            paths->L_r = lit ? L_r + beta_r * d_r : L_r;
            paths->L_g = lit ? L_g + beta_g * d_g : L_g;
            paths->L_b = lit ? L_b + beta_b * d_b : L_b;
        }
    }

    // Sample the BSDF to get the new path directions (Diffuse_Sample)
    vfloat r = V_Sqrt(u_bsdf0);
    vfloat cos_phi;
    vfloat sin_phi = V_SinCos2Pi(u_bsdf1, &cos_phi);
    vfloat wi_lx = r * cos_phi;
    vfloat wi_ly = r * sin_phi;
    vfloat wi_lz = V_Sqrt(V_Fmax((vfloat)0.0f, 1.0f - u_bsdf0));
    vfloat pdfW = ((wo_lz > 0.0f) & (wi_lz > 0.0f)) ? wi_lz * M_1_PI_F : 0.0f;
    running &= (pdfW > 0.0f) & ((albedo_r.v > 0.0f) | (albedo_g.v > 0.0f) | (albedo_b.v > 0.0f));
    paths->running = running;
    paths->beta_r = beta_r * albedo_r.v;
    paths->beta_g = beta_g * albedo_g.v;
    paths->beta_b = beta_b * albedo_b.v;
    paths->prev_pdfW = pdfW;
    paths->depth = depth + 1;
    dx = wi_lx * s_x + wi_ly * t_x + wi_lz * n_x;
    dy = wi_lx * s_y + wi_ly * t_y + wi_lz * n_y;
    dz = wi_lx * s_z + wi_ly * t_z + wi_lz * n_z;
    vfloat side = V_Dot3(dx, dy, dz, ng_x.v, ng_y.v, ng_z.v) > 0.0f ? error : -error;
    paths->dx = dx;
    paths->dy = dy;
    paths->dz = dz;
    paths->ox = p_x + side * ng_x.v;
    paths->oy = p_y + side * ng_y.v;
    paths->oz = p_z + side * ng_z.v;
}

// A lane's radiance to radiance[3 i ..]; a non-finite value is stored as 0 and counted (as
// pbrt does). Returns 1 if it was not finite.
CL_INLINE uint Store_Radiance(__global float *radiance, uint i, float r, float g, float b)
{
    float3 L = (float3)(r, g, b);
    // (isfinite without the builtin call: exponent bits not all set)
    bool finite = (as_uint(r) & 0x7f800000u) != 0x7f800000u &&
                  (as_uint(g) & 0x7f800000u) != 0x7f800000u &&
                  (as_uint(b) & 0x7f800000u) != 0x7f800000u;
    vstore3(finite ? L : (float3)(0.0f), i, radiance);
    return finite ? 0u : 1u;
}

CL_INLINE void Store_Counters(__global uint *counters, uint nonfinite, const LaneStats *stats)
{
    atomic_max(&counters[COUNTER_LAST_GROUP], (uint)get_group_id(0) + 1u);
    if (nonfinite)
        atomic_add(&counters[COUNTER_NONFINITE], nonfinite);
    atomic_add(&counters[COUNTER_RAYS], stats->rays);
    atomic_add(&counters[COUNTER_BOUNCE_STEPS], stats->bounce_steps);
    atomic_add(&counters[COUNTER_BOUNCE_LANES], stats->bounce_lanes);
    atomic_add(&counters[COUNTER_SHADOW_STEPS], stats->shadow_steps);
    atomic_add(&counters[COUNTER_SHADOW_LANES], stats->shadow_lanes);
}

#define SIMD_PATHS_ARGUMENTS                                                                   \
    uint traced_total, uint pixel_count, uint seed, uint image_width, uint image_height,       \
        int max_depth, __global const float2 *positions, __global const uint *traced_offsets,  \
        __global const uint *pixels, __global const uint *redraws,                             \
        __global const Camera *camera, __global const Quad *quads,                             \
        __global const QuadBlock *quad_blocks, uint quad_block_count,                          \
        __global const Material *materials, __global const Emitter *emitters,                  \
        __global float *radiance, __global uint *counters

#define PATH_SCENE_OF_ARGUMENTS                                                                \
    {.quads = quads, .quad_blocks = quad_blocks, .quad_block_count = quad_block_count,        \
     .materials = materials, .emitter = &emitters[0], .light = &quads[emitters[0].index],     \
     .seed = seed, .max_depth = max_depth}

// ----------------------------------------------------------------------------- the kernels

// One work-item per SIMD_WIDTH consecutive traced samples (trace_paths' arguments, restricted
// to the scene this prototype supports), a path a lane until all have ended: radiance (RGB
// float) to radiance[3 i .. 3 i + 2].
__kernel SIMD_ATTR void simd_paths(SIMD_PATHS_ARGUMENTS)
{
    uint first = get_global_id(0) * SIMD_WIDTH;
    if (first >= traced_total)
        return;
    PathScene scene = PATH_SCENE_OF_ARGUMENTS;

    // Each lane's sample: its pixel, its index in the pixel, its redraw and its position
    LANES(uint, vuint) pixel, sample, redraw;
    LANES(float, vfloat) pos_x, pos_y;
    LANES(int, vint) in_launch;
    for (int j = 0; j < SIMD_WIDTH; ++j) {
        uint i = first + (uint)j < traced_total ? first + (uint)j : traced_total - 1u;
        uint slot = Launch_OwnerPixel(traced_offsets, pixel_count, i);
        pixel.s[j] = pixels[slot];
        sample.s[j] = i - traced_offsets[slot];
        redraw.s[j] = redraws[slot];
        float2 u_pixel = positions[i];
        pos_x.s[j] = u_pixel.x;
        pos_y.s[j] = u_pixel.y;
        in_launch.s[j] = first + (uint)j < traced_total ? -1 : 0;
    }
    Paths paths;
    V_CameraRays(camera, image_width, image_height, pixel.v, pos_x.v, pos_y.v, &paths.dx,
                 &paths.dy, &paths.dz);
    paths.ox = (vfloat)(camera->origin[0]);
    paths.oy = (vfloat)(camera->origin[1]);
    paths.oz = (vfloat)(camera->origin[2]);
    paths.L_r = paths.L_g = paths.L_b = (vfloat)(0.0f);
    paths.beta_r = paths.beta_g = paths.beta_b = (vfloat)(1.0f);
    paths.prev_pdfW = (vfloat)(0.0f);
    paths.depth = (vint)(0);
    paths.pixel = pixel.v;
    paths.sample = sample.v;
    paths.redraw = redraw.v;
    paths.running = in_launch.v;

    // Trace until every lane's path has ended
    LaneStats stats = {0u, 0u, 0u, 0u, 0u};
    while (V_Bits(paths.running) != 0u)
        V_PathStep(&scene, &paths, &stats);

    LANES(float, vfloat) L_r, L_g, L_b;
    L_r.v = paths.L_r;
    L_g.v = paths.L_g;
    L_b.v = paths.L_b;
    uint nonfinite = 0u;
    for (int j = 0; j < SIMD_WIDTH; ++j) {
        if (first + (uint)j < traced_total)
            nonfinite += Store_Radiance(radiance, first + (uint)j, L_r.s[j], L_g.s[j], L_b.s[j]);
    }
    Store_Counters(counters, nonfinite, &stats);
}

// Samples per chunk of simd_paths_regen: SIMD_CHUNK lanes' worth.
#ifndef SIMD_CHUNK
#define SIMD_CHUNK 32
#endif
#define CHUNK_SAMPLES (SIMD_WIDTH * SIMD_CHUNK)

// How simd_paths_regen deals its chunks (CHUNK_SAMPLES consecutive traced samples each) to
// work-items. PoCL's pthread device deals whole work-groups to its T threads in runs of
// consecutive groups, each to the thread that asks first: 256 T groups a run while more than
// 256 T^2 remain, then 32 T (pthread_scheduler.c, get_wg_index_range, PoCL 3.0 and 3.1). With
// T = 2, work packed into the first 512 groups of a padded launch all goes to one thread.
#define SIMD_LAYOUT_FRONT 0  // work-item g runs chunk g: the work sits in the launch's first groups
#define SIMD_LAYOUT_SPREAD 1 // chunk c runs on work-item floor(c G / C), G work-items, C chunks
#define SIMD_LAYOUT_QUEUE 2  // each work-item takes chunk after chunk from a counter
// Queued, the first work-item each thread runs takes chunks until none are left, so the threads
// stay busy whatever the runs' sizes, and lanes refill across chunks; a sample's radiance does
// not depend on the lane or work-item that traces it (the lane counters do).
#ifndef SIMD_LAYOUT
#define SIMD_LAYOUT SIMD_LAYOUT_QUEUE
#endif

// The [*next, *end) samples of this work-item's first chunk; false if it has none.
CL_INLINE bool Regen_FirstChunk(__global uint *counters, uint traced_total, uint *next,
                                uint *end)
{
    uint chunks = (traced_total + (CHUNK_SAMPLES - 1u)) / CHUNK_SAMPLES;
    if (chunks == 0u)
        return false;
#if SIMD_LAYOUT == SIMD_LAYOUT_FRONT
    ulong chunk = get_global_id(0);
#elif SIMD_LAYOUT == SIMD_LAYOUT_SPREAD
    // The chunk c with floor(c G / C) == g, if any (C <= G: the host launches a work-item a
    // chunk at least)
    ulong g = get_global_id(0), size = get_global_size(0);
    ulong chunk = (g * chunks + size - 1u) / size;
    if (chunk * size / chunks != g)
        return false;
#else
    ulong chunk = atomic_inc(&counters[COUNTER_NEXT_CHUNK]);
#endif
    if (chunk >= chunks)
        return false;
    *next = (uint)chunk * CHUNK_SAMPLES;
    *end = traced_total - *next > CHUNK_SAMPLES ? *next + CHUNK_SAMPLES : traced_total;
    return true;
}

// The work-item's next chunk once its current one is all started: with SIMD_LAYOUT_QUEUE
// another from the counter (false when none are left), otherwise none.
CL_INLINE bool Regen_NextChunk(__global uint *counters, uint traced_total, uint *next,
                               uint *end)
{
#if SIMD_LAYOUT == SIMD_LAYOUT_QUEUE
    return Regen_FirstChunk(counters, traced_total, next, end);
#else
    return false;
#endif
}

// Path regeneration: a work-item traces chunks of CHUNK_SAMPLES consecutive traced samples
// (SIMD_LAYOUT says which); a lane whose path ends stores its radiance and starts the next
// sample at the next step, so lanes idle only at the end of the work-item's last chunk.
__kernel SIMD_ATTR void simd_paths_regen(SIMD_PATHS_ARGUMENTS)
{
    uint next, end;
    if (!Regen_FirstChunk(counters, traced_total, &next, &end))
        return;
    bool more = true; // chunks may be left to take
    PathScene scene = PATH_SCENE_OF_ARGUMENTS;
#if SIMD_WIDTH == 16
    const vuint lane_bit = (vuint)(1u, 2u, 4u, 8u, 16u, 32u, 64u, 128u, 256u, 512u, 1024u, 2048u,
                                   4096u, 8192u, 16384u, 32768u);
#else
    const vuint lane_bit = (vuint)(1u, 2u, 4u, 8u, 16u, 32u, 64u, 128u);
#endif
    const uint all_lanes = (1u << SIMD_WIDTH) - 1u;

    LANES(uint, vuint) pixel, sample, redraw, index;
    LANES(float, vfloat) pos_x, pos_y;
    pixel.v = sample.v = redraw.v = index.v = (vuint)(0u);
    pos_x.v = pos_y.v = (vfloat)(0.0f);
    Paths paths;
    paths.ox = paths.oy = paths.oz = paths.dx = paths.dy = paths.dz = (vfloat)(0.0f);
    paths.L_r = paths.L_g = paths.L_b = (vfloat)(0.0f);
    paths.beta_r = paths.beta_g = paths.beta_b = (vfloat)(1.0f);
    paths.prev_pdfW = (vfloat)(0.0f);
    paths.depth = (vint)(0);
    paths.pixel = paths.sample = paths.redraw = (vuint)(0u);
    paths.running = (vint)(0);
    LaneStats stats = {0u, 0u, 0u, 0u, 0u};
    uint nonfinite = 0u;
    for (;;) {
        // Start the next samples in the free lanes
        uint free_bits = ~V_Bits(paths.running) & all_lanes;
        uint fresh_bits = 0u;
        while (free_bits != 0u && more) {
            if (next >= end) {
                more = Regen_NextChunk(counters, traced_total, &next, &end);
                continue;
            }
            int j = __builtin_ctz(free_bits);
            free_bits &= free_bits - 1u;
            uint slot = Launch_OwnerPixel(traced_offsets, pixel_count, next);
            pixel.s[j] = pixels[slot];
            sample.s[j] = next - traced_offsets[slot];
            redraw.s[j] = redraws[slot];
            float2 u_pixel = positions[next];
            pos_x.s[j] = u_pixel.x;
            pos_y.s[j] = u_pixel.y;
            index.s[j] = next;
            fresh_bits |= 1u << j;
            ++next;
        }
        if (fresh_bits != 0u) {
            vint fresh = (lane_bit & fresh_bits) != 0u;
            vfloat dx, dy, dz;
            V_CameraRays(camera, image_width, image_height, pixel.v, pos_x.v, pos_y.v, &dx, &dy,
                         &dz);
            paths.dx = fresh ? dx : paths.dx;
            paths.dy = fresh ? dy : paths.dy;
            paths.dz = fresh ? dz : paths.dz;
            paths.ox = fresh ? camera->origin[0] : paths.ox;
            paths.oy = fresh ? camera->origin[1] : paths.oy;
            paths.oz = fresh ? camera->origin[2] : paths.oz;
            paths.L_r = fresh ? 0.0f : paths.L_r;
            paths.L_g = fresh ? 0.0f : paths.L_g;
            paths.L_b = fresh ? 0.0f : paths.L_b;
            paths.beta_r = fresh ? 1.0f : paths.beta_r;
            paths.beta_g = fresh ? 1.0f : paths.beta_g;
            paths.beta_b = fresh ? 1.0f : paths.beta_b;
            paths.prev_pdfW = fresh ? 0.0f : paths.prev_pdfW;
            paths.depth = fresh ? 0 : paths.depth;
            paths.pixel = pixel.v;
            paths.sample = sample.v;
            paths.redraw = redraw.v;
            paths.running |= fresh;
        }
        uint started = V_Bits(paths.running);
        if (started == 0u)
            break;
        V_PathStep(&scene, &paths, &stats);

        // Store the paths that ended
        uint ended = started & ~V_Bits(paths.running);
        if (ended != 0u) {
            LANES(float, vfloat) L_r, L_g, L_b;
            L_r.v = paths.L_r;
            L_g.v = paths.L_g;
            L_b.v = paths.L_b;
            while (ended != 0u) {
                int j = __builtin_ctz(ended);
                ended &= ended - 1u;
                nonfinite += Store_Radiance(radiance, index.s[j], L_r.s[j], L_g.s[j], L_b.s[j]);
            }
        }
    }
    Store_Counters(counters, nonfinite, &stats);
}
