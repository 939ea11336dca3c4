// Path tracing with SIMD_WIDTH paths per work-item, one path a vector lane (structure of arrays,
// a mask of the paths still running): the megakernel's integrator (integrator.cl trace_paths,
// kernels/integrator.h), laid out for CPU vector units. PoCL keeps a one-path-per-work-item
// kernel scalar on CPUs; here each float operation of a path vertex runs on all lanes at once.
//
// Contract: every sample's radiance, the rays counted and the non-finite count are trace_paths'
// TO THE BIT, for every scene, path sampler and option (tests/test_trace_simd.py). The vector
// code mirrors the megakernel's expression for expression (OpenCL C contracts a * b + c into an
// fma within one expression only, so products stay in the expression that sums them, exactly
// as in the scalar code), and whatever it does not cover runs, lane by lane, the megakernel's
// own functions:
//   intersection  vector: brute force over the quad blocks (in QuadBlock order, a block's
//                 bounding-box test per lane, so ties and skips go as in Scene_Intersect) and
//                 the spheres; scenes with triangles or a BVH: Scene_Intersect per lane;
//   surfaces      vector: quads; spheres and triangles: Scene_Surface per lane;
//   vertices      vector: diffuse surfaces and pure emitters; other materials (dielectric,
//                 rough conductor): the whole vertex by Integrator_Vertex per lane;
//   emission      vector: quad and triangle emitters; spheres' pdf: Light_HitPdfW per lane;
//   samples       vector: every path sampler (Philox, hashes, Owen scrambles, zsobol's digit
//                 permutations and stratified's permutation cycle walks on lanes);
//   NEE           vector: quad emitters (one emitter: its record read once; several: Light_Pick
//                 and a gather per lane); sphere and triangle emitters: Integrator_SampleDirect
//                 per lane; shadow rays: vector brute force as above, else Scene_Occluded;
//   roulette      vector (Roulette_EndProbability on lanes).
// Also per lane: the sampler's set-up and the tiny or huge vectors where Length3 or Normalize3
// fall back to the builtin.
//
// Path regeneration: a work-item traces a chunk of consecutive traced samples, and a lane whose
// path ends takes the chunk's next sample, so each lane has its own depth (its own sampler
// dimensions). Arguments and radiance layout: trace_paths'; counters: trace_paths' (non-finite
// count, rays per work-group), then the steps taken (COUNTER_STEPS: the host allocates one
// more, zeroed).
//
// Build options: SIMD_WIDTH 16 (default) or 8. SIMD_PORTABLE: no x86 builtins (sqrt and the
// lane mask's bits by portable code), as a compiler without __AVX512F__ / __AVX__ gets anyway.
// SIMD_CHUNK: lanes' worth of samples in a work-item's chunk (32; the host checks it is
// positive and SIMD_WIDTH x SIMD_CHUNK below 2^31).
#include "integrator.h"

#include "sampler_lanes.h"
#include "simd_lanes.h"

// ----------------------------------------------------------------------------- geometry

// Rays on lanes: origins, directions, and the directions' reciprocals (bounding-box tests).
typedef struct {
    vfloat ox, oy, oz, dx, dy, dz, ix, iy, iz;
} Rays;

// The slab test of Bounds_Hit on lanes: where each lane's ray can meet the box before tmax.
SIMD_FN vint V_BoundsHit(__global const float *lower, __global const float *upper,
                         const Rays *r, vfloat tmax)
{
    vfloat t0x = (lower[0] - r->ox) * r->ix;
    vfloat t0y = (lower[1] - r->oy) * r->iy;
    vfloat t0z = (lower[2] - r->oz) * r->iz;
    vfloat t1x = (upper[0] - r->ox) * r->ix;
    vfloat t1y = (upper[1] - r->oy) * r->iy;
    vfloat t1z = (upper[2] - r->oz) * r->iz;
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

// QuadBlock_BoundsHit on lanes (a block flagged as enclosing the scene: every lane).
SIMD_FN vint V_BlockReached(__global const QuadBlock *block, const Rays *r, vfloat tmax)
{
    if (block->lower[3] != 0.0f)
        return (vint)(-1);
    return V_BoundsHit(block->lower, block->upper, r, tmax);
}

// Hit mask of lane j of a QuadBlock (QuadBlock_Hits' operations, one quad against all lanes)
// before tmax, its distances in *t_out.
SIMD_FN vint V_QuadHits(__global const QuadBlock *block, int j, const Rays *r, vfloat tmax,
                        vfloat *t_out)
{
    float nx = block->normal[0][j];
    float ny = block->normal[1][j];
    float nz = block->normal[2][j];
    vfloat t = (block->plane_d[j] - (nx * r->ox + ny * r->oy + nz * r->oz)) /
               (nx * r->dx + ny * r->dy + nz * r->dz);
    vfloat rx = r->ox + t * r->dx - block->corner[0][j];
    vfloat ry = r->oy + t * r->dy - block->corner[1][j];
    vfloat rz = r->oz + t * r->dz - block->corner[2][j];
    vfloat a = rx * block->u_dual[0][j] + ry * block->u_dual[1][j] + rz * block->u_dual[2][j];
    vfloat b = rx * block->v_dual[0][j] + ry * block->v_dual[1][j] + rz * block->v_dual[2][j];
    *t_out = t;
    return (t > 0.0f) & (t < tmax) & (a >= 0.0f) & (a <= 1.0f) & (b >= 0.0f) & (b <= 1.0f);
}

// Sphere_Intersect on lanes: the distance to the nearest crossing ahead, or tmax.
SIMD_FN vfloat V_SphereIntersect(__global const Sphere *s, const Rays *r, vfloat tmax)
{
    vfloat ocx = r->ox - s->center[0];
    vfloat ocy = r->oy - s->center[1];
    vfloat ocz = r->oz - s->center[2];
    vfloat radius = (vfloat)(s->radius);
    vfloat b = V_Dot3(ocx, ocy, ocz, r->dx, r->dy, r->dz);
    vfloat fx = ocx - b * r->dx;
    vfloat fy = ocy - b * r->dy;
    vfloat fz = ocz - b * r->dz;
    vfloat disc = radius * radius - V_Dot3(fx, fy, fz, fx, fy, fz);
    vfloat c = V_Dot3(ocx, ocy, ocz, ocx, ocy, ocz) - radius * radius;
    vfloat q = -b - V_Copysign(V_Sqrt(disc), b);
    vfloat t0 = c / q;
    vfloat t1 = q;
    vfloat tnear = V_Fmin(t0, t1);
    vfloat tfar = V_Fmax(t0, t1);
    vfloat t = tnear > 0.0f ? tnear : tfar;
    vint hit = (disc >= 0.0f) & (t > 0.0f) & (t < tmax);
    return hit ? t : tmax;
}

// Scene_Intersect by brute force on lanes (no triangles, no BVH): the closest hit's distance
// (INFINITY if none) and hit id in *prim (-1 if none), for the lanes of `running`.
SIMD_FN vfloat V_Intersect(const SceneData *scene, vint running, const Rays *r, vint *prim)
{
    vfloat t = (vfloat)(INFINITY);
    vint id = (vint)(-1);
    for (uint b = 0; b < scene->quad_block_count; ++b) {
        __global const QuadBlock *block = &scene->quad_blocks[b];
        vint reached = running & V_BlockReached(block, r, t);
        if (V_Bits(reached) == 0u)
            continue;
        // The lanes that do not reach the block test its quads against a tmax of 0, which no
        // hit (t > 0) is below: no per-quad mask
        vfloat t_block = reached ? t : 0.0f;
        for (int j = 0; j < QUAD_BLOCK_WIDTH; ++j) {
            int q = block->quad[j];
            if (q < 0)
                continue;
            vfloat tq;
            vint hit = V_QuadHits(block, j, r, t_block, &tq);
            t_block = hit ? tq : t_block;
            id = hit ? (vint)q : id;
        }
        t = reached ? t_block : t;
    }
    for (uint i = 0; i < scene->sphere_count; ++i) {
        vfloat ti = V_SphereIntersect(&scene->spheres[i], r, t);
        id = ti < t ? (vint)(int)(scene->quad_count + i) : id;
        t = ti;
    }
    *prim = id;
    return t;
}

// Scene_Occluded by brute force on lanes (no triangles, no BVH): where something lies along
// the ray before tmax, for the lanes of `tested` (the others' answers are meaningless).
SIMD_FN vint V_Occluded(const SceneData *scene, vint tested, const Rays *r, vfloat tmax)
{
    vint blocked = (vint)(0);
    for (uint i = 0; i < scene->sphere_count; ++i)
        blocked |= V_SphereIntersect(&scene->spheres[i], r, tmax) < tmax;
    for (uint b = scene->quad_block_count; b-- > 0u;) {
        vint open = tested & ~blocked;
        if (V_Bits(open) == 0u)
            break;
        __global const QuadBlock *block = &scene->quad_blocks[b];
        vint reached = open & V_BlockReached(block, r, tmax);
        if (V_Bits(reached) == 0u)
            continue;
        // (tmax 0 for the lanes that do not reach the block, as in V_Intersect)
        vfloat tmax_block = reached ? tmax : 0.0f;
        for (int j = 0; j < QUAD_BLOCK_WIDTH; ++j) {
            if (block->quad[j] < 0)
                continue;
            vfloat tq;
            blocked |= V_QuadHits(block, j, r, tmax_block, &tq);
        }
    }
    return blocked;
}

// Camera_Direction on lanes, through Integrator_SamplePosition's image positions (the pixel's
// corner plus a half plus the position in it); Normalize3's builtin lane by lane for tiny or
// huge vectors.
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
    vfloat s = V_Dot3(x, y, z, x, y, z);
    vfloat inv = 1.0f / V_Sqrt(s);
    vfloat nx = x * inv;
    vfloat ny = y * inv;
    vfloat nz = z * inv;
    uint odd_bits = V_Bits(~((s >= 0x1p-126f) & (s < INFINITY)));
    FOR_EACH_LANE(j, odd_bits)
    {
        float3 d = normalize((float3)(x[j], y[j], z[j]));
        nx[j] = d.x;
        ny[j] = d.y;
        nz[j] = d.z;
    }
    *dx = nx;
    *dy = ny;
    *dz = nz;
}

// ----------------------------------------------------------------------------- paths on lanes

// SIMD_WIDTH paths (PathState on lanes) and whether each goes on.
typedef struct {
    vfloat ox, oy, oz, dx, dy, dz;
    vfloat L_r, L_g, L_b;
    vfloat beta_r, beta_g, beta_b;
    vfloat prev_pdfW, eta_scale;
    vint specular; // -1 where the last BSDF sample was specular
    vint depth;    // each path's vertex count so far (its lane's sampler dimensions)
    vint running;  // -1 where the path goes on
} Paths;

// The launch's settings and each lane's sample, shared by the steps.
typedef struct {
    int max_depth, nee, russian_roulette, paths_kind;
    uint seed;
    vuint pixel, sample, redraw; // the independent sampler's Philox streams
    SamplerLanes ld;             // the stratified, sobol and zsobol samplers'
    Strata strata;               // the stratified sampler's
    Sampler sampler[SIMD_WIDTH];
} Lanes;

CL_INLINE PathState Paths_Lane(const Paths *paths, uint j)
{
    PathState path;
    path.L = (float3)(paths->L_r[j], paths->L_g[j], paths->L_b[j]);
    path.beta = (float3)(paths->beta_r[j], paths->beta_g[j], paths->beta_b[j]);
    path.origin = (float3)(paths->ox[j], paths->oy[j], paths->oz[j]);
    path.dir = (float3)(paths->dx[j], paths->dy[j], paths->dz[j]);
    path.prev_pdfW = paths->prev_pdfW[j];
    path.eta_scale = paths->eta_scale[j];
    path.specularBounce = paths->specular[j] != 0;
    return path;
}

CL_INLINE void Paths_SetLane(Paths *paths, uint j, const PathState *path, bool running)
{
    paths->L_r[j] = path->L.x;
    paths->L_g[j] = path->L.y;
    paths->L_b[j] = path->L.z;
    paths->beta_r[j] = path->beta.x;
    paths->beta_g[j] = path->beta.y;
    paths->beta_b[j] = path->beta.z;
    paths->ox[j] = path->origin.x;
    paths->oy[j] = path->origin.y;
    paths->oz[j] = path->origin.z;
    paths->dx[j] = path->dir.x;
    paths->dy[j] = path->dir.y;
    paths->dz[j] = path->dir.z;
    paths->prev_pdfW[j] = path->prev_pdfW;
    paths->eta_scale[j] = path->eta_scale;
    paths->specular[j] = path->specularBounce ? -1 : 0;
    paths->running[j] = running ? -1 : 0;
}

// Whether the scene is traced by the vector brute force (no triangles, no BVH).
CL_INLINE bool V_SceneOnLanes(const SceneData *scene)
{
    return scene->bvh_node_count == 0u && scene->triangle_count == 0u;
}

// One vertex of every running path (Integrator_Li's loop, Integrator_Vertex on lanes): the
// closest surfaces, their emission, then next event estimation and the BSDF's next directions.
// Lanes whose path ends have running cleared; the others have their next ray.
SIMD_FN void V_PathStep(const SceneData *scene, const Lanes *lanes, Paths *paths, uint *rays)
{
    vint depth = paths->depth;
    vint running = paths->running;
    uint running_bits = V_Bits(running);
    *rays += (uint)popcount(running_bits);
    Rays ray;
    ray.ox = paths->ox;
    ray.oy = paths->oy;
    ray.oz = paths->oz;
    ray.dx = paths->dx;
    ray.dy = paths->dy;
    ray.dz = paths->dz;
    ray.ix = 1.0f / ray.dx;
    ray.iy = 1.0f / ray.dy;
    ray.iz = 1.0f / ray.dz;

    // Find the closest surface along the rays (by brute force on lanes, else lane by lane)
    vint prim = (vint)(-1);
    vfloat t = (vfloat)(INFINITY);
    if (V_SceneOnLanes(scene)) {
        t = V_Intersect(scene, running, &ray, &prim);
    }
    else {
        FOR_EACH_LANE(j, running_bits)
        {
            int prim_j;
            float3 o = (float3)(ray.ox[j], ray.oy[j], ray.oz[j]);
            float3 d = (float3)(ray.dx[j], ray.dy[j], ray.dz[j]);
            t[j] = Scene_Intersect(scene, o, d, INFINITY, &prim_j);
            prim[j] = prim_j;
        }
    }
    running &= prim >= 0;
    running_bits = V_Bits(running);

    // The surfaces' records: every lane's quad read (a lane that hit something else reads the
    // first quad, replaced below), the point and its error on lanes; spheres' and triangles'
    // lane by lane from Scene_Surface
    LANES(float, vfloat) ng_x_l, ng_y_l, ng_z_l, corner_abs_l, albedo_r_l, albedo_g_l, albedo_b_l;
    LANES(int, vint) prims_l, material_l, emitter_l, two_sided_l, scalar_vertex_l;
    prims_l.v = prim;
    if (scene->quad_count > 0u) {
        for (int j = 0; j < SIMD_WIDTH; ++j) {
            int p = prims_l.s[j];
            __global const Quad *q = &scene->quads[p >= 0 && p < (int)scene->quad_count ? p : 0];
            ng_x_l.s[j] = q->normal[0];
            ng_y_l.s[j] = q->normal[1];
            ng_z_l.s[j] = q->normal[2];
            corner_abs_l.s[j] = MaxAbs3(Load3(q->corner));
            material_l.s[j] = q->material;
            emitter_l.s[j] = q->emitter;
        }
    } else {
        ng_x_l.v = ng_y_l.v = ng_z_l.v = corner_abs_l.v = (vfloat)(0.0f);
        material_l.v = emitter_l.v = (vint)(-1);
    }
    vfloat p_x = ray.ox + t * ray.dx;
    vfloat p_y = ray.oy + t * ray.dy;
    vfloat p_z = ray.oz + t * ray.dz;
    vfloat magnitude = V_MaxAbs3(ray.ox, ray.oy, ray.oz) +
                       t * V_MaxAbs3(ray.dx, ray.dy, ray.dz) + corner_abs_l.v;
    vfloat error = SURFACE_ERROR_SCALE * magnitude;
    vint other_hit = running & (prim >= (int)scene->quad_count);
    uint other_bits = V_Bits(other_hit);
    vfloat ns_x, ns_y, ns_z;
    if (other_bits != 0u) {
        LANES(float, vfloat) sn_x, sn_y, sn_z, sp_x, sp_y, sp_z, s_error;
        FOR_EACH_LANE(j, other_bits)
        {
            float3 o = (float3)(ray.ox[j], ray.oy[j], ray.oz[j]);
            float3 d = (float3)(ray.dx[j], ray.dy[j], ray.dz[j]);
            Surface surface = Scene_Surface(scene, o, d, t[j], prims_l.s[j]);
            ng_x_l.s[j] = surface.ng.x;
            ng_y_l.s[j] = surface.ng.y;
            ng_z_l.s[j] = surface.ng.z;
            sn_x.s[j] = surface.ns.x;
            sn_y.s[j] = surface.ns.y;
            sn_z.s[j] = surface.ns.z;
            sp_x.s[j] = surface.p.x;
            sp_y.s[j] = surface.p.y;
            sp_z.s[j] = surface.p.z;
            s_error.s[j] = surface.error;
            material_l.s[j] = surface.material;
            emitter_l.s[j] = surface.emitter;
        }
        p_x = other_hit ? sp_x.v : p_x;
        p_y = other_hit ? sp_y.v : p_y;
        p_z = other_hit ? sp_z.v : p_z;
        error = other_hit ? s_error.v : error;
        ns_x = other_hit ? sn_x.v : ng_x_l.v;
        ns_y = other_hit ? sn_y.v : ng_y_l.v;
        ns_z = other_hit ? sn_z.v : ng_z_l.v;
    } else {
        ns_x = ng_x_l.v;
        ns_y = ng_y_l.v;
        ns_z = ng_z_l.v;
    }

    // Their materials: diffuse ones on lanes, the others' vertices lane by lane below (a lane
    // on a pure emitter reads a material it does not use: any lane's, if some lane has one)
    vint has_material = material_l.v >= 0;
    uint material_bits = V_Bits(has_material);
    if (material_bits != 0u) {
        int any_material = material_l.s[Ctz(material_bits)];
        for (int j = 0; j < SIMD_WIDTH; ++j) {
            int k = material_l.s[j];
            __global const Material *m = &scene->materials[k >= 0 ? k : any_material];
            albedo_r_l.s[j] = m->albedo[0];
            albedo_g_l.s[j] = m->albedo[1];
            albedo_b_l.s[j] = m->albedo[2];
            two_sided_l.s[j] = m->two_sided;
            scalar_vertex_l.s[j] = m->type != MATERIAL_DIFFUSE ? -1 : 0;
        }
        scalar_vertex_l.v &= has_material;
    } else {
        albedo_r_l.v = albedo_g_l.v = albedo_b_l.v = (vfloat)(0.0f);
        two_sided_l.v = scalar_vertex_l.v = (vint)(0);
    }

    vfloat ng_x = ng_x_l.v, ng_y = ng_y_l.v, ng_z = ng_z_l.v;
    vfloat albedo_r = albedo_r_l.v, albedo_g = albedo_g_l.v, albedo_b = albedo_b_l.v;
    vint material = material_l.v, emitter = emitter_l.v, two_sided = two_sided_l.v;
    vint scalar_vertex = scalar_vertex_l.v & running;

    // Vertices on other materials than diffuse: the megakernel's, lane by lane
    uint scalar_bits = V_Bits(scalar_vertex);
    FOR_EACH_LANE(j, scalar_bits)
    {
        PathState path = Paths_Lane(paths, j);
        bool goes_on = Integrator_Vertex(scene, &path, depth[j], t[j], prim[j], lanes->max_depth,
                                         lanes->nee, lanes->russian_roulette,
                                         &lanes->sampler[j], rays);
        Paths_SetLane(paths, j, &path, goes_on);
    }
    vint vector_lanes = running & ~scalar_vertex;
    vint scalar_on = paths->running & scalar_vertex;
    if (V_Bits(vector_lanes) == 0u) {
        paths->running = scalar_on;
        return;
    }
    vfloat wo_x = -ray.dx, wo_y = -ray.dy, wo_z = -ray.dz;
    vfloat cos_o = V_Dot3(ng_x, ng_y, ng_z, wo_x, wo_y, wo_z);

    // Add emission found by the rays, MIS-weighted unless they came from the camera or a
    // specular bounce (NEE cannot sample those paths)
    vfloat L_r = paths->L_r, L_g = paths->L_g, L_b = paths->L_b;
    vfloat beta_r = paths->beta_r, beta_g = paths->beta_g, beta_b = paths->beta_b;
    vint emitted = vector_lanes & (emitter >= 0) & (cos_o > 0.0f);
    uint emitted_bits = V_Bits(emitted);
    if (emitted_bits != 0u) {
        vfloat Le_r, Le_g, Le_b, pick_pdf, area;
        vint sphere_lanes;
        if (scene->emitter_count == 1u) {
            // One emitter: its record read once
            __global const Emitter *e = &scene->emitters[0];
            Le_r = (vfloat)(e->radiance[0]);
            Le_g = (vfloat)(e->radiance[1]);
            Le_b = (vfloat)(e->radiance[2]);
            pick_pdf = (vfloat)(e->pick_pdf);
            area = (vfloat)(e->area);
            sphere_lanes = (vint)(e->shape == EMITTER_SPHERE ? -1 : 0);
        } else {
            LANES(float, vfloat) Le_r_l, Le_g_l, Le_b_l, pick_pdf_l, area_l;
            LANES(int, vint) hit_emitter_l, sphere_l;
            hit_emitter_l.v = emitter;
            for (int j = 0; j < SIMD_WIDTH; ++j) {
                int k = hit_emitter_l.s[j];
                __global const Emitter *e = &scene->emitters[k >= 0 ? k : 0];
                Le_r_l.s[j] = e->radiance[0];
                Le_g_l.s[j] = e->radiance[1];
                Le_b_l.s[j] = e->radiance[2];
                pick_pdf_l.s[j] = e->pick_pdf;
                area_l.s[j] = e->area;
                sphere_l.s[j] = e->shape == EMITTER_SPHERE ? -1 : 0;
            }
            Le_r = Le_r_l.v;
            Le_g = Le_g_l.v;
            Le_b = Le_b_l.v;
            pick_pdf = pick_pdf_l.v;
            area = area_l.v;
            sphere_lanes = sphere_l.v;
        }
        vint full_weight = paths->specular | (depth == 0) | (vint)(!lanes->nee ? -1 : 0);
        // Light_HitPdfW: a quad's or triangle's here, a sphere's lane by lane
        vfloat light_pdfW = pick_pdf * t * t / (cos_o * area);
        uint sphere_bits = V_Bits(emitted & ~full_weight & sphere_lanes);
        FOR_EACH_LANE(j, sphere_bits)
        {
            float3 o = (float3)(ray.ox[j], ray.oy[j], ray.oz[j]);
            light_pdfW[j] = Light_HitPdfW(scene, &scene->emitters[emitter[j]], o, t[j], cos_o[j]);
        }
        vfloat a2 = paths->prev_pdfW * paths->prev_pdfW;
        vfloat mis = a2 / (a2 + light_pdfW * light_pdfW);
        L_r = emitted ? (full_weight ? L_r + beta_r * Le_r : L_r + beta_r * Le_r * mis) : L_r;
        L_g = emitted ? (full_weight ? L_g + beta_g * Le_g : L_g + beta_g * Le_g * mis) : L_g;
        L_b = emitted ? (full_weight ? L_b + beta_b * Le_b : L_b + beta_b * Le_b * mis) : L_b;
    }

    // End paths at the maximum depth, on surfaces that only emit, and one-sided surfaces
    // seen from behind
    vint on = vector_lanes & (material >= 0) & (depth != lanes->max_depth);
    vint back = cos_o < 0.0f;
    on &= ~back | (two_sided != 0);
    paths->L_r = vector_lanes ? L_r : paths->L_r;
    paths->L_g = vector_lanes ? L_g : paths->L_g;
    paths->L_b = vector_lanes ? L_b : paths->L_b;
    paths->running = scalar_on | on;
    uint on_bits = V_Bits(on);
    if (on_bits == 0u)
        return;
    vfloat n_x = back ? -ns_x : ns_x;
    vfloat n_y = back ? -ns_y : ns_y;
    vfloat n_z = back ? -ns_z : ns_z;

    // Shading frame (Frame_FromNormal) and wo in it (z only: all a diffuse BSDF needs)
    vfloat sign = AS_VFLOAT((AS_VUINT(n_z) & 0x80000000u) | 0x3f800000u);
    vfloat fa = -1.0f / (sign + n_z);
    vfloat fb = n_x * n_y * fa;
    vfloat s_x = 1.0f + sign * n_x * n_x * fa;
    vfloat s_y = sign * fb;
    vfloat s_z = -sign * n_x;
    vfloat t_x = fb;
    vfloat t_y = sign + n_y * n_y * fa;
    vfloat t_z = -n_y;
    vfloat wo_lz = V_Dot3(wo_x, wo_y, wo_z, n_x, n_y, n_z);

    // The vertex's random numbers (Sampler_Bounce on lanes; lane by lane for any other kind)
    vfloat u_choice, u_point0, u_point1, u_roulette, u_dir0, u_dir1, u_lobe;
    if (lanes->paths_kind == PATHS_INDEPENDENT) {
        vuint dim = 1u + 2u * AS_VUINT(depth);
        V_Uniform4Lanes(lanes->seed, lanes->pixel, lanes->sample, dim, lanes->redraw, &u_choice,
                        &u_point0, &u_point1, &u_roulette);
        vfloat unused;
        V_Uniform4Lanes(lanes->seed, lanes->pixel, lanes->sample, dim + 1u, lanes->redraw,
                        &u_dir0, &u_dir1, &u_lobe, &unused);
    } else if (lanes->paths_kind == PATHS_SOBOL || lanes->paths_kind == PATHS_ZSOBOL) {
        V_SobolBounce(&lanes->ld, AS_VUINT(depth), &u_choice, &u_point0, &u_point1, &u_lobe,
                      &u_dir0, &u_dir1, &u_roulette);
    } else if (lanes->paths_kind == PATHS_STRATIFIED) {
        V_StratifiedBounce(&lanes->ld, &lanes->strata, lanes->seed, lanes->pixel, lanes->redraw,
                           AS_VUINT(depth), &u_choice, &u_point0, &u_point1, &u_lobe, &u_dir0,
                           &u_dir1, &u_roulette);
    } else {
        u_choice = u_point0 = u_point1 = u_roulette = u_dir0 = u_dir1 = u_lobe = (vfloat)(0.5f);
        FOR_EACH_LANE(j, on_bits)
        {
            BounceSamples u = Sampler_Bounce(&lanes->sampler[j], (uint)depth[j]);
            u_choice[j] = u.emitter_choice;
            u_point0[j] = u.emitter_point.x;
            u_point1[j] = u.emitter_point.y;
            u_lobe[j] = u.lobe;
            u_dir0[j] = u.direction.x;
            u_dir1[j] = u.direction.y;
            u_roulette[j] = u.roulette;
        }
    }

    // Sample direct illumination from the emitters (Integrator_SampleDirect): quad emitters
    // on lanes, the others lane by lane
    if (lanes->nee && scene->emitter_count > 0u) {
        vint quad_light = on;
        vfloat c_x, c_y, c_z, e1_x, e1_y, e1_z, e2_x, e2_y, e2_z, ln_x, ln_y, ln_z;
        vfloat Le_r, Le_g, Le_b, pick_pdf, area;
        if (scene->emitter_count == 1u && scene->emitters[0].shape == EMITTER_QUAD) {
            // One quad emitter: its records read once
            __global const Emitter *e = &scene->emitters[0];
            __global const Quad *q = &scene->quads[e->index];
            c_x = (vfloat)(q->corner[0]);
            c_y = (vfloat)(q->corner[1]);
            c_z = (vfloat)(q->corner[2]);
            e1_x = (vfloat)(q->edge1[0]);
            e1_y = (vfloat)(q->edge1[1]);
            e1_z = (vfloat)(q->edge1[2]);
            e2_x = (vfloat)(q->edge2[0]);
            e2_y = (vfloat)(q->edge2[1]);
            e2_z = (vfloat)(q->edge2[2]);
            ln_x = (vfloat)(q->normal[0]);
            ln_y = (vfloat)(q->normal[1]);
            ln_z = (vfloat)(q->normal[2]);
            Le_r = (vfloat)(e->radiance[0]);
            Le_g = (vfloat)(e->radiance[1]);
            Le_b = (vfloat)(e->radiance[2]);
            pick_pdf = (vfloat)(e->pick_pdf);
            area = (vfloat)(e->area);
        } else {
            // Light_Pick lane by lane; quads gathered, other shapes lane by lane
            c_x = c_y = c_z = e1_x = e1_y = e1_z = e2_x = e2_y = e2_z = (vfloat)(0.0f);
            ln_x = ln_y = ln_z = Le_r = Le_g = Le_b = pick_pdf = area = (vfloat)(0.0f);
            FOR_EACH_LANE(j, on_bits)
            {
                uint picked = Light_Pick(scene, u_choice[j]);
                __global const Emitter *e = &scene->emitters[picked];
                if (e->shape != EMITTER_QUAD) {
                    quad_light[j] = 0;
                    Surface s;
                    s.p = (float3)(p_x[j], p_y[j], p_z[j]);
                    s.ng = (float3)(ng_x[j], ng_y[j], ng_z[j]);
                    s.ns = (float3)(ns_x[j], ns_y[j], ns_z[j]);
                    s.material = material[j];
                    s.emitter = emitter[j];
                    s.error = error[j];
                    Frame frame = Frame_FromNormal((float3)(n_x[j], n_y[j], n_z[j]));
                    float3 wo = (float3)(wo_x[j], wo_y[j], wo_z[j]);
                    float3 d = Integrator_SampleDirect(
                        scene, &s, frame, &scene->materials[material[j]],
                        Frame_ToLocal(frame, wo), (float3)(u_choice[j], u_point0[j], u_point1[j]),
                        rays);
                    float3 beta = (float3)(beta_r[j], beta_g[j], beta_b[j]);
                    float3 L = (float3)(paths->L_r[j], paths->L_g[j], paths->L_b[j]);
                    L += beta * d;
                    paths->L_r[j] = L.x;
                    paths->L_g[j] = L.y;
                    paths->L_b[j] = L.z;
                    continue;
                }
                __global const Quad *q = &scene->quads[e->index];
                c_x[j] = q->corner[0];
                c_y[j] = q->corner[1];
                c_z[j] = q->corner[2];
                e1_x[j] = q->edge1[0];
                e1_y[j] = q->edge1[1];
                e1_z[j] = q->edge1[2];
                e2_x[j] = q->edge2[0];
                e2_y[j] = q->edge2[1];
                e2_z[j] = q->edge2[2];
                ln_x[j] = q->normal[0];
                ln_y[j] = q->normal[1];
                ln_z[j] = q->normal[2];
                Le_r[j] = e->radiance[0];
                Le_g[j] = e->radiance[1];
                Le_b[j] = e->radiance[2];
                pick_pdf[j] = e->pick_pdf;
                area[j] = e->area;
            }
        }
        // A point uniform by area on each lane's quad (Light_SampleLi)
        vfloat y_x = c_x + u_point0 * e1_x + u_point1 * e2_x;
        vfloat y_y = c_y + u_point0 * e1_y + u_point1 * e2_y;
        vfloat y_z = c_z + u_point0 * e1_z + u_point1 * e2_z;
        vfloat to_x = y_x - p_x;
        vfloat to_y = y_y - p_y;
        vfloat to_z = y_z - p_z;
        // Length3 (the builtin lane by lane for tiny or huge vectors)
        vfloat dist2 = V_Dot3(to_x, to_y, to_z, to_x, to_y, to_z);
        vfloat dist = V_Sqrt(dist2);
        uint odd_bits = V_Bits(quad_light & ~((dist2 >= 0x1p-126f) & (dist2 < INFINITY)));
        FOR_EACH_LANE(j, odd_bits)
        {
            dist[j] = length((float3)(to_x[j], to_y[j], to_z[j]));
        }
        vfloat wi_x = to_x / dist;
        vfloat wi_y = to_y / dist;
        vfloat wi_z = to_z / dist;
        vfloat cos_light = -V_Dot3(ln_x, ln_y, ln_z, wi_x, wi_y, wi_z);
        vfloat light_pdfW = pick_pdf * dist * dist / (cos_light * area);
        vint lit = quad_light & (cos_light > 0.0f) & (light_pdfW > 0.0f);
        // The diffuse BSDF's value times the cosine (BSDF_Eval * Fabs(wi_local.z))
        vfloat wi_lz = V_Dot3(wi_x, wi_y, wi_z, n_x, n_y, n_z);
        vint same_side = (wo_lz > 0.0f) & (wi_lz > 0.0f);
        vfloat cos_i = V_Fabs(wi_lz);
        vfloat f_r = (same_side ? albedo_r * M_1_PI_F : 0.0f) * cos_i;
        vfloat f_g = (same_side ? albedo_g * M_1_PI_F : 0.0f) * cos_i;
        vfloat f_b = (same_side ? albedo_b * M_1_PI_F : 0.0f) * cos_i;
        lit &= (f_r > 0.0f) | (f_g > 0.0f) | (f_b > 0.0f);
        uint lit_bits = V_Bits(lit);
        vfloat direct_r = (vfloat)(0.0f), direct_g = (vfloat)(0.0f), direct_b = (vfloat)(0.0f);
        if (lit_bits != 0u) {
            // The shadow ray stops short of the emitter by both points' rounding bounds
            vfloat side = V_Dot3(wi_x, wi_y, wi_z, ng_x, ng_y, ng_z) > 0.0f ? error : -error;
            Rays shadow;
            shadow.ox = p_x + side * ng_x;
            shadow.oy = p_y + side * ng_y;
            shadow.oz = p_z + side * ng_z;
            shadow.dx = wi_x;
            shadow.dy = wi_y;
            shadow.dz = wi_z;
            vfloat light_error =
                SURFACE_ERROR_SCALE *
                V_MaxAbs3(p_x + dist * wi_x, p_y + dist * wi_y, p_z + dist * wi_z);
            vfloat tmax = dist - 2.0f * (error + light_error);
            *rays += (uint)popcount(lit_bits);
#ifndef PROFILE_SKIP_SHADOW_RAYS // profiling build: every shadow ray counts as unblocked
            if (V_SceneOnLanes(scene)) {
                shadow.ix = 1.0f / wi_x;
                shadow.iy = 1.0f / wi_y;
                shadow.iz = 1.0f / wi_z;
                lit &= ~V_Occluded(scene, lit, &shadow, tmax);
            } else {
                FOR_EACH_LANE(j, lit_bits)
                {
                    float3 o = (float3)(shadow.ox[j], shadow.oy[j], shadow.oz[j]);
                    float3 d = (float3)(wi_x[j], wi_y[j], wi_z[j]);
                    lit[j] = Scene_Occluded(scene, o, d, tmax[j]) ? 0 : -1;
                }
            }
#endif
            // Power heuristic against the BSDF's pdf (Diffuse_PdfW)
            vfloat bsdf_pdfW = same_side ? wi_lz * M_1_PI_F : 0.0f;
            vfloat a2 = light_pdfW * light_pdfW;
            vfloat weight = a2 / (a2 + bsdf_pdfW * bsdf_pdfW);
            vfloat scale = weight / light_pdfW;
            vfloat d_r = f_r * Le_r * scale;
            vfloat d_g = f_g * Le_g * scale;
            vfloat d_b = f_b * Le_b * scale;
            direct_r = lit ? d_r : 0.0f;
            direct_g = lit ? d_g : 0.0f;
            direct_b = lit ? d_b : 0.0f;
        }
        // Added at every vertex that sampled a light, lit or not (as the megakernel: an
        // infinite throughput times a zero contribution is NaN there too)
        vfloat L_r = paths->L_r + beta_r * direct_r;
        vfloat L_g = paths->L_g + beta_g * direct_g;
        vfloat L_b = paths->L_b + beta_b * direct_b;
        paths->L_r = quad_light ? L_r : paths->L_r;
        paths->L_g = quad_light ? L_g : paths->L_g;
        paths->L_b = quad_light ? L_b : paths->L_b;
    }

    // Sample the BSDF to get the new path directions (Diffuse_Sample)
    vfloat r = V_Sqrt(u_dir0);
    vfloat cos_phi;
    vfloat sin_phi = V_SinCos2Pi(u_dir1, &cos_phi);
    vfloat wi_lx = r * cos_phi;
    vfloat wi_ly = r * sin_phi;
    vfloat wi_lz = V_Sqrt(V_Fmax((vfloat)(0.0f), 1.0f - u_dir0));
    vfloat pdfW = ((wo_lz > 0.0f) & (wi_lz > 0.0f)) ? wi_lz * M_1_PI_F : 0.0f;
    vint sampled = (pdfW > 0.0f) & ((albedo_r > 0.0f) | (albedo_g > 0.0f) | (albedo_b > 0.0f));
    beta_r = beta_r * albedo_r;
    beta_g = beta_g * albedo_g;
    beta_b = beta_b * albedo_b;
    vfloat dx = wi_lx * s_x + wi_ly * t_x + wi_lz * n_x;
    vfloat dy = wi_lx * s_y + wi_ly * t_y + wi_lz * n_y;
    vfloat dz = wi_lx * s_z + wi_ly * t_z + wi_lz * n_z;
    vfloat side = V_Dot3(dx, dy, dz, ng_x, ng_y, ng_z) > 0.0f ? error : -error;
    vfloat ox = p_x + side * ng_x;
    vfloat oy = p_y + side * ng_y;
    vfloat oz = p_z + side * ng_z;

    // Possibly terminate the paths with Russian roulette (Roulette_EndProbability)
    vint roulette_lanes = on & (depth >= RUSSIAN_ROULETTE_MIN_DEPTH);
    if (lanes->russian_roulette && V_Bits(roulette_lanes) != 0u) {
        vfloat rr_beta_max = V_Fmax(beta_r, V_Fmax(beta_g, beta_b));
        if (RUSSIAN_ROULETTE_ETA_SCALE)
            rr_beta_max *= paths->eta_scale;
        vfloat q = rr_beta_max < 1.0f ? V_Fmax((vfloat)(0.0f), 1.0f - rr_beta_max) : 0.0f;
        q = roulette_lanes ? q : 0.0f;
        vint rouletted = q > 0.0f;
        sampled &= ~(rouletted & (u_roulette < q));
        beta_r = rouletted ? beta_r / (1.0f - q) : beta_r;
        beta_g = rouletted ? beta_g / (1.0f - q) : beta_g;
        beta_b = rouletted ? beta_b / (1.0f - q) : beta_b;
    }
    paths->beta_r = on ? beta_r : paths->beta_r;
    paths->beta_g = on ? beta_g : paths->beta_g;
    paths->beta_b = on ? beta_b : paths->beta_b;
    paths->prev_pdfW = on ? pdfW : paths->prev_pdfW;
    paths->specular = on ? (vint)(0) : paths->specular;
    paths->dx = on ? dx : paths->dx;
    paths->dy = on ? dy : paths->dy;
    paths->dz = on ? dz : paths->dz;
    paths->ox = on ? ox : paths->ox;
    paths->oy = on ? oy : paths->oy;
    paths->oz = on ? oz : paths->oz;
    paths->running = scalar_on | (on & sampled);
}

// ----------------------------------------------------------------------------- the kernel

// Samples a work-item traces: SIMD_CHUNK lanes' worth.
#ifndef SIMD_CHUNK
#define SIMD_CHUNK 32
#endif
#if SIMD_CHUNK < 1
#error "SIMD_CHUNK must be positive"
#endif
#define CHUNK_SAMPLES (SIMD_WIDTH * SIMD_CHUNK)

// counters[COUNTER_RAYS + groups] (the host allocates it past the per-group ray counts,
// zeroed) sums the work-items' steps (V_PathStep calls), for lane occupancy figures and tests.
#define COUNTER_STEPS(groups) (COUNTER_RAYS + (groups))

// The traced samples [*first, *end) of this work-item's chunk; false if it has none. Chunk c
// runs on work-item floor(c G / C) of the G launched (C chunks, C <= G: the host launches a
// work-item per SIMD_WIDTH samples), so busy work-items spread over the whole launch: PoCL's
// pthread device deals runs of consecutive work-groups to its threads, and a launch's busy
// work-items packed at its front would all sit in the first run, on one thread (Intel's
// runtime, its work-items scalar, also ran the spread chunks faster than chunk g on work-item
// g). A queue of chunks taken with atomic_inc kept PoCL's threads as busy, and Debian's and
// pip's PoCL then crashed at times as the process released the kernel after compiling it.
CL_INLINE bool Simd_Chunk(uint traced_total, uint *first, uint *end)
{
    uint chunks = traced_total / CHUNK_SAMPLES + (traced_total % CHUNK_SAMPLES != 0u);
    ulong g = get_global_id(0), size = get_global_size(0);
    ulong chunk = (g * chunks + size - 1u) / size;
    if (chunk >= chunks || chunk * size / chunks != g)
        return false;
    *first = (uint)chunk * CHUNK_SAMPLES;
    *end = traced_total - *first > CHUNK_SAMPLES ? *first + CHUNK_SAMPLES : traced_total;
    return true;
}

// Path regeneration: a work-item traces a chunk of CHUNK_SAMPLES consecutive traced samples,
// a path a lane; a lane whose path ends stores its radiance (RGB float to radiance[3 i .. 3 i
// + 2], as trace_paths) and takes the chunk's next sample, so lanes idle only at the chunk's
// end. Each lane's path is a function of its sample alone: which lane or work-item traces a
// sample changes no bit of its radiance, nor the launch's ray and non-finite counts.
__kernel SIMD_ATTR KERNEL_SCALAR_WORK_ITEMS void
trace_paths_simd(uint traced_total, uint pixel_count, uint seed, uint image_width,
                 uint image_height, int max_depth, int nee, int russian_roulette,
                 int paths_kind, uint fixed_count, uint strata, uint zsobol_log2_count,
                 uint zsobol_bits, __global const float2 *positions,
                 __global const uint *traced_offsets, __global const uint *pixels,
                 __global const uint *redraws, __global const Camera *camera,
                 __global const Quad *quads, __global const QuadBlock *quad_blocks,
                 uint quad_count, uint quad_block_count, __global const Sphere *spheres,
                 uint sphere_count, __global const Material *materials,
                 __global const Emitter *emitters, uint emitter_count,
                 __global const Triangle *triangles, uint triangle_count,
                 __global const TriangleNormals *triangle_normals,
                 __global const BVHNode *bvh_nodes, uint bvh_node_count,
                 __global const uint *bvh_prims, __global float *radiance,
                 __global uint *counters)
{
    uint next, end;
    if (!Simd_Chunk(traced_total, &next, &end))
        return;
    SceneData scene = SCENE_DATA_OF_ARGUMENTS;
    const uint all_lanes = (1u << SIMD_WIDTH) - 1u;

    // Each lane's sample: its pixel, index in the pixel, sampler and traced index (lanes that
    // never take one keep sample 0 of pixel 0, and do not run)
    Lanes lanes;
    lanes.max_depth = max_depth;
    lanes.nee = nee;
    lanes.russian_roulette = russian_roulette;
    lanes.paths_kind = paths_kind;
    lanes.seed = seed;
    lanes.ld.kind = paths_kind;
    lanes.ld.zsobol_bits = zsobol_bits;
    if (paths_kind == PATHS_STRATIFIED)
        lanes.strata = Strata_Make(fixed_count, strata);
    LANES(uint, vuint) pixel_l, sample_l, redraw_l, key_x_l, key_y_l, sobol_index_l, traced_l;
    LANES(float, vfloat) pos_x_l, pos_y_l;
    pixel_l.v = sample_l.v = redraw_l.v = key_x_l.v = key_y_l.v = sobol_index_l.v = (vuint)(0u);
    traced_l.v = (vuint)(0u);
    pos_x_l.v = pos_y_l.v = (vfloat)(0.0f);
    Paths paths;
    paths.ox = paths.oy = paths.oz = paths.dx = paths.dy = paths.dz = (vfloat)(0.0f);
    paths.L_r = paths.L_g = paths.L_b = (vfloat)(0.0f);
    paths.beta_r = paths.beta_g = paths.beta_b = (vfloat)(1.0f);
    paths.prev_pdfW = (vfloat)(0.0f);
    paths.eta_scale = (vfloat)(1.0f);
    paths.specular = paths.depth = paths.running = (vint)(0);
    uint slot_end = 0u; // where the samples of the last sample's pixel end
    uint slot = 0u;
    uint rays = 0u, steps = 0u, nonfinite = 0u;
    for (;;) {
        // Start the chunk's next samples in the free lanes (Launch_OwnerPixel searched only
        // when a sample leaves the last one's pixel)
        uint free_bits = ~V_Bits(paths.running) & all_lanes;
        uint fresh_bits = 0u;
        LANES(int, vint) fresh_l;
        fresh_l.v = (vint)(0);
        while (free_bits != 0u && next < end) {
            uint j = (uint)Ctz(free_bits);
            free_bits &= free_bits - 1u;
            if (next >= slot_end) {
                slot = Launch_OwnerPixel(traced_offsets, pixel_count, next);
                slot_end = slot + 1u < pixel_count ? traced_offsets[slot + 1u] : UINT_MAX;
            }
            uint pixel = pixels[slot];
            uint sample = next - traced_offsets[slot];
            pixel_l.s[j] = pixel;
            sample_l.s[j] = sample;
            redraw_l.s[j] = redraws[slot];
            float2 u_pixel = positions[next];
            pos_x_l.s[j] = u_pixel.x;
            pos_y_l.s[j] = u_pixel.y;
            traced_l.s[j] = next;
            lanes.sampler[j] = Sampler_Make(paths_kind, seed, pixel, sample, redraws[slot],
                                            fixed_count, strata, image_width, zsobol_log2_count,
                                            zsobol_bits);
            key_x_l.s[j] = lanes.sampler[j].key.x;
            key_y_l.s[j] = lanes.sampler[j].key.y;
            sobol_index_l.s[j] =
                paths_kind == PATHS_ZSOBOL ? lanes.sampler[j].zsobol_index : sample;
            fresh_bits |= 1u << j;
            fresh_l.s[j] = -1;
            ++next;
        }
        if (fresh_bits != 0u) {
            vint fresh = fresh_l.v;
            lanes.pixel = pixel_l.v;
            lanes.sample = sample_l.v;
            lanes.redraw = redraw_l.v;
            lanes.ld.key_x = key_x_l.v;
            lanes.ld.key_y = key_y_l.v;
            lanes.ld.index = sobol_index_l.v;
            vfloat dx, dy, dz;
            V_CameraRays(camera, image_width, image_height, pixel_l.v, pos_x_l.v, pos_y_l.v, &dx,
                         &dy, &dz);
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
            paths.eta_scale = fresh ? 1.0f : paths.eta_scale;
            paths.specular = fresh ? 0 : paths.specular;
            paths.depth = fresh ? 0 : paths.depth;
            paths.running |= fresh;
        }
        uint started = V_Bits(paths.running);
        if (started == 0u)
            break;
        V_PathStep(&scene, &lanes, &paths, &rays);
        paths.depth += 1;
        ++steps;

        // Store the radiance of the paths that ended; a non-finite value is counted and
        // stored as 0 (as pbrt does)
        uint ended = started & ~V_Bits(paths.running);
        FOR_EACH_LANE(j, ended)
        {
            float3 L = (float3)(paths.L_r[j], paths.L_g[j], paths.L_b[j]);
            if (!all(isfinite(L))) {
                ++nonfinite;
                L = (float3)(0.0f);
            }
            vstore3(L, traced_l.s[j], radiance);
        }
    }
    if (nonfinite != 0u)
        atomic_add(&counters[COUNTER_NONFINITE], nonfinite);
    atomic_add(&counters[COUNTER_RAYS + get_group_id(0)], rays);
    atomic_add(&counters[COUNTER_STEPS(get_num_groups(0))], steps);
}
