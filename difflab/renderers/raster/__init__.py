"""The rasterizer: vertices -> clip space -> near-plane clipping -> z-buffer -> shading points -> image.

`driver.rasterize(compiled, settings)` takes the frame's arrays and launches the stages, kernels in
`clip` (1-2), `coverage` (3), `resolve` (4-5; flat / Gouraud points: `flat_gouraud`) and `shade` (6-7).

Stages (each a kernel; per-pixel ones are launched in row bands on all cores):
1. `clip_vertices_kernel`  world -> clip space.
2. `assemble_kernel`       clip each triangle against the near plane (z_clip >= -w_clip) into at most
                           two triangles, divide by w, map to raster space, snap to 1/256 sample
                           (fixed point), drop degenerate ones, cull back faces on request.
3. `raster_kernel`         per band of rows, the triangles `assemble_kernel` counted and `bin_kernel`
                           listed there: for every sample centre inside a triangle (exact integer
                           edge functions with a top-left-style fill rule: a shared edge's samples go
                           to exactly one triangle) write min(depth, triangle) into a 64-bit
                           visibility key: the z-buffer test and a deterministic tie-break in one
                           atomic.
4. `resolve_kernel`        per sample: barycentrics of the winning triangle, perspective-correct
                           (b_k / w_k renormalised) or affine, the original triangle's weights, and the
                           surface there (position, normal, uv, material, depth) — the G-buffer. Under
                           Phong shading an analytic sphere's sample takes the sphere's exact point on
                           its eye ray, normal (p - c) / r and uv (`resolve.sphere_sample`).
5. shading points          phong: every covered sample; flat: every face (lit at its centroid with the
                           face normal); gouraud: every vertex, twice (front and back normal, OpenGL's
                           two-sided lighting).
6. `light_points_kernel`   per point and light: direction, distance, shadow-ray visibility, and the
                           colour from the one illumination model.
7. `compose_kernel`        per sample: the weighted colours of its points (gouraud: the vertex colours
                           interpolated, optionally clamped to [0, 1] first), background, fog.

With the G-buffer under Phong shading (whose points are its samples), stages 4 and 6 run as one
pass (`shade.phong_gbuffer_kernel`: each sample resolved, then lit); `render_frame(...,
image=False)` skips stage 7 there, and a fit's frame (`api.fit_frame`) the lighting too: only the
light geometry is recorded (`shade.GEOMETRY_ONLY`), uv and its derivatives only where a texture is
sampled.
The G-buffer's arrays, in their structs, come from `CompiledScene.reusable_structs` (the last
frame's when nothing holds them any more); those an empty sample leaves zero share one buffer,
cleared in one memset beside stages 1-3 (on a pool worker); the kernels write the rest. From
128^2 samples the per-sample passes run a band per core even where the z-buffer runs on one
thread (`launch.pass_threads`), each band dealt blocks of rows across the whole frame
(`launch.launch_row_loops`; on CUDA a thread per sample); up to 256^2 the z-buffer is drawn as
two halves of the triangles on two threads, which then go on to their bands of the pass
(`bandpool.run_phases`).

`render` (no G-buffer) runs stages 1-3, then `image_kernel` fuses 4-7 per sample: Phong's points are
its samples; a flat / Gouraud point is lit when a sample first reads it, into a cache of the CPU
thread (`shade.PointCacheW`), so only the points visible samples read are lit, with no pass of
their own. The image kernel also resets the keys it reads, so the next frame's z-buffer starts
cleared.
"""
