"""The rasterizer's G-buffer without the image (`render_frame(..., image=False)`, what fits render),
and the frame buffers a compiled scene reuses once no frame holds them."""

import dataclasses
import functools
import gc
import threading
import time
import weakref

import numpy as np
import pytest

from conftest import scene_dict
from test_raster_spheres import sphere_scene
from difflab import RenderError, compile_scene, render_frame, save_image
from difflab._warp import wp
from difflab.renderers import bandpool, launch
from difflab.renderers.api import fit_frame
from difflab.renderers.raster import coverage, driver, shade
from difflab.renderers.camera import camera_struct
from difflab.scene import Scene

LIGHTS = [{"type": "point", "position": [2, 3, 4], "intensity": [0.9, 0.8, 0.7]},
          {"type": "directional", "direction": [1, -1, -1], "intensity": [0.3, 0.3, 0.3]}]
CAMERA = {"eye": [0.5, 1.0, 4.0], "target": [0, 0, 0], "fov_y": 40, "width": 24, "height": 20}


def fields(gbuffer) -> dict:
    """Every array of a G-buffer (its shading points' too) and its other fields, by name."""
    out = {}
    for f in dataclasses.fields(gbuffer):
        value = getattr(gbuffer, f.name)
        if f.name == "points":
            out.update({f"points.{p.name}": getattr(value, p.name) for p in dataclasses.fields(value)})
        else:
            out[f.name] = value
    return out


def assert_same_gbuffer(got, want):
    got, want = fields(got), fields(want)
    assert got.keys() == want.keys()
    for name, value in want.items():
        if isinstance(value, np.ndarray):
            assert got[name].dtype == value.dtype and np.array_equal(got[name], value, equal_nan=True), name
        else:
            assert repr(got[name]) == repr(value), name


def textured_scene(tmp_path, shading: str, spp: int) -> Scene:
    texture = tmp_path / "texture.png"
    save_image(texture, np.random.default_rng(3).random((8, 8, 3)).astype(np.float32))
    materials = {"ball": {"ka": 0.1, "kd": [0.6, 0.3, 0.2], "ks": 0.4, "n": 20},
                 "floor": {"kd": 0.7, "texture": str(texture)}}
    objects = [{"type": "sphere", "center": [0, 0.2, 0], "radius": 0.7, "material": "ball"},
               {"type": "plane", "point": [0, -0.5, 0], "normal": [0, 1, 0], "material": "floor"}]
    return Scene.from_dict(scene_dict(objects, materials, camera=CAMERA, lights=LIGHTS, ambient=(0.2, 0.2, 0.2),
                                      background=[0.1, 0.2, 0.3],
                                      render={"shading": shading, "spp": spp, "shadows": True}))


@pytest.mark.parametrize("shading", ["phong", "flat", "gouraud"])
@pytest.mark.parametrize("spp", [1, 4])
def test_the_image_less_frame_has_the_full_frames_gbuffer_field_by_field(tmp_path, shading, spp):
    compiled = compile_scene(textured_scene(tmp_path, shading, spp))
    full = render_frame(compiled)
    bare = render_frame(compiled, image=False)
    assert bare.image is None and full.image.shape == (20, 24, 3)
    assert_same_gbuffer(bare.gbuffer, full.gbuffer)
    assert {k: v for k, v in bare.stats.items() if k != "seconds"} == \
        {k: v for k, v in full.stats.items() if k != "seconds"}
    assert bare.gbuffer.mask.any() and (bare.gbuffer.material == 1).any()  # the ball and the textured floor seen


@pytest.mark.parametrize("shading", ["phong", "flat", "gouraud"])
def test_per_sample_passes_split_over_threads_give_the_one_thread_frame(tmp_path, monkeypatch, shading):
    """From PASS_POOL_MIN_SAMPLES samples (lowered here to this small frame's) the G-buffer passes
    run in a band per core while the z-buffer stays on one thread: the same buffers, bit for bit."""
    monkeypatch.delenv("DIFFLAB_THREADS", raising=False)
    monkeypatch.setattr(launch, "PASS_POOL_MIN_SAMPLES", 1)
    monkeypatch.setattr(launch, "cpu_threads", lambda: 3)  # 3 bands (the 20 rows dealt in blocks), whatever the machine
    monkeypatch.setattr(bandpool, "cpu_threads", lambda: 3)  # (and 3 threads to run them)
    launched, real_row_bands = [], launch.row_bands
    monkeypatch.setattr(launch, "row_bands", lambda n, k: launched.append(k) or real_row_bands(n, k))
    compiled = compile_scene(textured_scene(tmp_path, shading, 1))
    split = render_frame(compiled)
    assert launched and set(launched) == {3}  # every banded launch was one band per thread
    one = render_frame(compiled, threads=1)
    assert_same_gbuffer(split.gbuffer, one.gbuffer)
    assert np.array_equal(split.image, one.image)


@pytest.mark.parametrize("shading", ["phong", "gouraud"])
def test_a_zbuffer_drawn_in_two_halves_gives_the_one_thread_frame_and_leaves_both_cleared(tmp_path, monkeypatch,
                                                                                          shading):
    """Where the z-buffer stays on one thread but the passes get every core (`launch.halved_zbuffer`),
    it is drawn as two halves of the slots on two threads, each sample taking the lesser key: the
    same buffers bit for bit as one thread's, frame after frame (both key arrays left all NO_HIT)."""
    monkeypatch.delenv("DIFFLAB_THREADS", raising=False)
    monkeypatch.setattr(launch, "PASS_POOL_MIN_SAMPLES", 1)
    monkeypatch.setattr(launch, "cpu_threads", lambda: 2)
    monkeypatch.setattr(bandpool, "cpu_threads", lambda: 2)
    halves = []
    real = driver.zbuffer
    monkeypatch.setattr(driver, "zbuffer", lambda *a, **k: halves.append(k.get("halves")) or real(*a, **k))
    scene = textured_scene(tmp_path, shading, 1)
    compiled = compile_scene(scene)
    one = render_frame(scene, threads=1)
    for image in (True, False, True):
        halved = render_frame(compiled, image=image)
        assert halves[-1] is not None and halves[-1][0].shape == (24 * 20,)
        assert_same_gbuffer(halved.gbuffer, one.gbuffer)
        for name in ("key", "partial key"):
            assert (compiled.scratch(name, 24 * 20, wp.int64).numpy() == coverage.NO_HIT).all(), name
    assert halves[0] is None and np.array_equal(halved.image, one.image)  # the threads=1 frame: one z-buffer


@wp.kernel
def mark_rows_kernel(row0: int, row_step: int, span: int, touched: wp.array2d(dtype=wp.int32),
                     band: wp.array(dtype=wp.int32), slots: wp.array(dtype=wp.int32)):
    i, j0, j1, slot = launch.dealt_span(row0, row_step, span, touched.shape[1], wp.tid())
    for j in range(j0, j1):
        touched[i, j] = touched[i, j] + 1
    band[i] = row0 // launch.ROW_BLOCK
    slots[slot] = slots[slot] + 1


@pytest.mark.parametrize("per_sample", [False, True])
@pytest.mark.parametrize("rows", [1, 7, 8, 9, 61, 256])
@pytest.mark.parametrize("threads, per_thread", [(1, 4), (2, 1), (3, 4)])
def test_row_loops_deal_each_row_once_in_blocks_to_even_bands(rows, threads, per_thread, per_sample, monkeypatch):
    """`launch_row_loops` deals blocks of ROW_BLOCK rows to its bands in turn (block b to band
    b mod n): every row once, no band more than a block longer than another (where the frame's
    content sits in part of it, contiguous bands left a core idle), and no band without a block.
    Each sample is covered by one thread -- the whole row's (the CPU's mapping) or its own (CUDA's,
    forced by PER_SAMPLE) -- and each slot of a per-thread count (`row_spans` a row) by one."""
    monkeypatch.setattr(launch, "PER_SAMPLE", per_sample)
    cols = 5
    touched = wp.zeros((rows, cols), dtype=wp.int32, device="cpu")
    band = wp.full(rows, -1, dtype=wp.int32, device="cpu")
    slots = wp.zeros(rows * launch.row_spans(cols, "cpu"), dtype=wp.int32, device="cpu")
    assert launch.row_spans(cols, "cpu") == (cols if per_sample else 1)
    launched, real = [], launch.run_bands
    monkeypatch.setattr(launch, "run_bands", lambda run, bands, threads=None: launched.append(len(bands)) or
                        real(run, bands, threads))
    launch.launch_row_loops(mark_rows_kernel, (rows, cols), [touched, band, slots], "cpu", threads, per_thread)
    n_bands = len(launch.band_plan(rows, "cpu", threads, per_thread))
    assert n_bands == (1 if threads == 1 else min(threads * per_thread, rows))
    assert launched == [min(n_bands, -(-rows // launch.ROW_BLOCK))]
    assert (touched.numpy() == 1).all() and (slots.numpy() == 1).all()
    expected = (np.arange(rows) // launch.ROW_BLOCK) % n_bands
    assert np.array_equal(band.numpy(), expected)
    sizes = np.bincount(expected)
    assert sizes.max() - sizes.min() <= launch.ROW_BLOCK


@wp.kernel
def add_at_kernel(index: int, value: int, out: wp.array(dtype=wp.int32)):
    out[index] = out[index] + value


def test_a_kept_launch_replays_only_the_same_inputs():
    """`launch_kept` (the z-buffer's launches of scratch arrays): recorded once per kernel, plan and
    band, replayed while the inputs are the same objects and numbers, recorded anew for any other
    (the new array or value is the one written); another plan's records replace the kernel's."""
    kept, first, second = {}, wp.zeros(2, dtype=wp.int32, device="cpu"), wp.zeros(2, dtype=wp.int32, device="cpu")
    launch.launch_kept(kept, add_at_kernel, "ab", 1, [0, 5, first], "cpu")
    recorded = kept[("launch", add_at_kernel)][1][0][2]
    launch.launch_kept(kept, add_at_kernel, "ab", 1, [0, 5, first], "cpu")
    assert first.numpy().tolist() == [10, 0] and kept[("launch", add_at_kernel)][1][0][2] is recorded
    launch.launch_kept(kept, add_at_kernel, "ab", 1, [0, 5, second], "cpu")
    launch.launch_kept(kept, add_at_kernel, "ab", 1, [0, 7, second], "cpu")
    launch.launch_kept(kept, add_at_kernel, "ab", 1, [1, 1, second], "cpu")  # another band: kept beside
    launch.launch_kept(None, add_at_kernel, "ab", 1, [1, 2, second], "cpu")  # nothing kept
    assert first.numpy().tolist() == [10, 0] and second.numpy().tolist() == [12, 3]
    assert kept[("launch", add_at_kernel)][0] == "ab" and sorted(kept[("launch", add_at_kernel)][1]) == [0, 1]
    launch.launch_kept(kept, add_at_kernel, "a", 1, [0, 1, second], "cpu")  # another plan: band 1's record gone
    assert second.numpy().tolist() == [13, 3] and list(kept) == [("launch", add_at_kernel)]
    assert kept[("launch", add_at_kernel)][0] == "a" and list(kept[("launch", add_at_kernel)][1]) == [0]


def test_threads_recording_bands_of_a_new_plan_at_once_keep_every_band():
    """Pool workers record the bands of one new plan in the caller's dict at once (`launch_kept`):
    one entry for the plan holds every band's record, and each band's launch ran once."""
    kept, out, n = {}, wp.zeros(8, dtype=wp.int32, device="cpu"), 8
    launch.launch_kept(kept, add_at_kernel, "old", 1, [0, 100, out], "cpu")
    start = threading.Barrier(n)

    def band(k):
        start.wait()
        launch.launch_kept(kept, add_at_kernel, ("new", n), 1, [k, k + 1, out], "cpu")
    threads = [threading.Thread(target=band, args=(k,)) for k in range(n)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert out.numpy().tolist() == [101, 2, 3, 4, 5, 6, 7, 8]
    assert kept[("launch", add_at_kernel)][0] == ("new", n) and sorted(kept[("launch", add_at_kernel)][1]) == list(
        range(n))


def test_a_smaller_frame_frees_the_launches_kept_for_a_larger_one():
    """A thread keeps only each kernel's last band plan's launches (`launch.kept_records`): after a
    64^2 fit frame (8 bands of dealt rows on two threads) and a 16^2 one (2 bands) on one compiled
    scene, every array of the 64^2 G-buffer is freed once its frame is (the records of bands 2-7
    held them through their structs), and a repeated 16^2 frame replays the pass's records."""
    compiled = compile_scene(Scene.from_dict(sphere_scene("outside", size=64)))
    big = fit_frame(compiled, threads=2)
    pool = compiled.scratch_pool()
    arrays = [weakref.ref(array) for array in pool[("structs", "fit gbuffer")][1]]
    assert len(arrays) > 10 and all(array() is not None for array in arrays)
    small_view = compiled.with_scene(Scene.from_dict(sphere_scene("outside", size=16)))
    small = fit_frame(small_view, threads=2)
    del big
    gc.collect()
    assert [array() for array in arrays] == [None] * len(arrays)
    plan, records = pool[("launch", shade.phong_gbuffer_kernel)]
    assert plan == (2, 16) and sorted(records) == [0, launch.ROW_BLOCK]
    first = {band: record[2] for band, record in records.items()}
    normal = small.gbuffer.normal.copy()
    del small  # its structs are reused unheld, so the next frame's launches are the same
    again = fit_frame(small_view, threads=2)
    assert {band: record[2] for band, record in pool[("launch", shade.phong_gbuffer_kernel)][1].items()} == first
    assert np.array_equal(again.gbuffer.normal, normal)


def test_run_bands_runs_each_band_once_and_hands_a_bands_error_to_the_caller():
    seen = []
    bandpool.run_bands(lambda a, b: seen.append((a, b)), [(0, 2), (2, 5), (5, 6), (6, 9)], threads=3)
    assert sorted(seen) == [(0, 2), (2, 5), (5, 6), (6, 9)]

    def fail_on_second(a, b):
        if a == 2:
            raise RenderError("band 2")
    with pytest.raises(RenderError, match="^band 2$"):
        bandpool.run_bands(fail_on_second, [(0, 2), (2, 5), (5, 6)], threads=2)


@pytest.mark.parametrize("threads", [1, 2, 3])
def test_run_phases_runs_each_phase_after_the_last_and_a_bands_error_stops_the_later_phases(threads):
    """`run_phases` (the halved z-buffer, then the G-buffer's pass on the same threads): every band of
    a phase once, each only once every band of the phase before has ended; a band's error is raised
    to the caller and no band of a later phase starts."""
    log, lock = [], threading.Lock()

    def band(phase):
        def run(a, b):
            with lock:
                log.append(("start", phase, a))
            time.sleep(0.002 * (a % 2))  # uneven bands: a thread done early must wait, not move on
            with lock:
                log.append(("end", phase, a))
        return run
    phases = [(band(0), [(0, 2), (1, 2)]), (band(1), [(k, 3) for k in range(3)]), (band(2), [(0, 1)])]
    bandpool.run_phases(phases, threads)
    for phase, n in enumerate((2, 3, 1)):
        assert sorted(a for event, p, a in log if event == "start" and p == phase) == list(range(n))
        first_start = min(i for i, (event, p, a) in enumerate(log) if event == "start" and p == phase)
        assert all(p >= phase for event, p, a in log[first_start:]), log

    def fail(a, b):
        raise RenderError(f"band {a}")
    later = []
    with pytest.raises(RenderError, match="^band [01]$"):
        bandpool.run_phases([(fail, [(0, 2), (1, 2)]), (lambda a, b: later.append(a), [(0, 2), (1, 2)])], threads)
    time.sleep(0.05)  # a worker that went on would have run a band by now
    assert later == []


def test_run_bands_keeps_one_pool_per_thread_count():
    """However many bands a call has, its workers come from the pool of its thread count (a pool per
    band count once left a new set of threads behind for every short launch)."""
    before = set(bandpool._pools)
    for count in range(2, 10):
        bandpool.run_bands(lambda a, b: None, [(i, i + 1) for i in range(count)], threads=7)
    assert set(bandpool._pools) - before <= {6} and 6 in bandpool._pools


class _FirstWaitInterrupted:
    """An event whose first wait is interrupted (Ctrl-C), as the caller's wait in `join` may be."""

    def __init__(self, event):
        self.event, self.waits = event, 0

    def wait(self, timeout=None):
        self.waits += 1
        if self.waits == 1:
            raise KeyboardInterrupt
        return self.event.wait(timeout)

    def set(self):
        self.event.set()


def test_an_interrupt_while_waiting_stops_bands_from_starting_and_lets_running_ones_end():
    """Ctrl-C in the caller's wait: the bands not started never start, and the one a worker runs
    ends before the interrupt reaches the caller (it must not write a frame's buffers afterwards)."""
    started, running, release = [], threading.Event(), threading.Event()

    def band(a, b):
        started.append(a)
        if a == 0:  # the worker's band, held until released
            running.set()
            release.wait(60)
            started.append("end")

    queue = bandpool._BandQueue(band, [(0, 1), (1, 2), (2, 3)])
    queue.finished = _FirstWaitInterrupted(queue.finished)
    bandpool._pool(1).submit(queue.work)
    assert running.wait(60)
    queue.work = lambda: None  # the caller is interrupted before it took a band
    threading.Timer(0.2, release.set).start()
    with pytest.raises(KeyboardInterrupt):
        queue.join()
    assert started == [0, "end"] and queue.run_band is None


def test_run_bands_over_no_band_returns():
    """No band: nothing is run and nothing waited for (the band queue once waited for ever for a
    band to finish; a daemon thread keeps a hang from stopping the test run)."""
    returned = threading.Event()
    threading.Thread(target=lambda: (bandpool.run_bands(pytest.fail, [], threads=3), returned.set()),
                     daemon=True).start()
    assert returned.wait(60), "run_bands([]) did not return"


@pytest.mark.parametrize("threads", [1, 2])
def test_a_task_started_beside_runs_once_and_join_hands_back_its_error(threads):
    """`start_beside` (the G-buffer's clearing beside the z-buffer): done exactly once by `join`,
    on a worker or on the caller, and a task's error raised there."""
    done = []
    bandpool.start_beside(lambda: done.append(1), "cpu", threads).join()
    assert done == [1]

    def fail():
        raise RenderError("cleared nothing")
    with pytest.raises(RenderError, match="^cleared nothing$"):
        bandpool.start_beside(fail, "cpu", threads).join()
    nothing = bandpool.start_beside(None, "cpu", threads)
    assert nothing.finished.is_set()  # nothing to do: done at once, no worker woken
    nothing.join()


@pytest.mark.parametrize("threads", [1, 2])
def test_a_joined_task_lets_go_of_what_it_captured(threads):
    """After `join`, the handle (which a pool worker may still hold a moment) no longer refers to the
    task: a frame's buffers that its clearing captured are reusable by the next frame at once. (The
    handle kept them alive: a 128^2+ frame's G-buffer was reused only now and then.)"""
    held = np.zeros(4)
    ref = weakref.ref(held)
    handle = bandpool.start_beside(functools.partial(held.fill, 1.0), "cpu", threads)
    handle.join()
    del held
    assert ref() is None


@pytest.mark.parametrize("method", ["raster", "raytrace"])
def test_image_false_drops_the_image_of_either_renderer(tmp_path, method):
    frame = render_frame(textured_scene(tmp_path, "phong", 1), method=method, image=False)
    assert frame.image is None and frame.stats["method"] == method


def test_image_must_be_a_bool(tmp_path):
    with pytest.raises(RenderError, match=r"^image: expected True or False, got 'no'$"):
        render_frame(textured_scene(tmp_path, "phong", 1), image="no")


@pytest.mark.parametrize("shading, spp", [("phong", 1), ("phong", 4), ("flat", 1)])
def test_a_non_finite_image_less_frame_is_refused_as_the_full_one(shading, spp):
    scene = Scene.from_dict(scene_dict([{"type": "sphere", "center": [0, 0, 0], "radius": 0.8, "material": "m"}],
                                       {"m": {"kd": 3e38, "ks": 3e38}}, lights=LIGHTS[:1],
                                       render={"shading": shading, "spp": spp}))
    messages = []
    for image in (True, False):
        with pytest.raises(RenderError, match=r"^render: \d+ of 1024 pixels are not finite \(float32 overflow\)") \
                as caught:
            render_frame(scene, image=image)
        messages.append(str(caught.value))
    assert messages[0] == messages[1]


def test_a_kept_gbuffer_survives_later_frames_of_other_views(tmp_path):
    scene = textured_scene(tmp_path, "phong", 1)
    compiled = compile_scene(scene)
    first = render_frame(compiled, image=False).gbuffer
    kept = {name: np.copy(value) for name, value in fields(first).items() if isinstance(value, np.ndarray)}
    moved = scene.with_overrides(camera=dict(CAMERA, eye=[-1.5, 0.5, 3.0]))
    second = render_frame(compiled.with_scene(moved), image=False).gbuffer
    assert not np.array_equal(second.position, first.position)  # another view
    for name, value in kept.items():
        assert np.array_equal(fields(first)[name], value, equal_nan=True), name
    assert_same_gbuffer(first, render_frame(scene, image=False).gbuffer)  # and it is still view 1's


def test_a_dropped_frames_buffers_are_reused_by_the_next_frame(tmp_path):
    compiled = compile_scene(textured_scene(tmp_path, "phong", 1))
    address = lambda frame: frame.gbuffer.position.__array_interface__["data"][0]  # noqa: E731
    frame = render_frame(compiled, image=False)
    first = address(frame)
    del frame
    again = render_frame(compiled, image=False)
    assert address(again) == first  # no fresh memory to fault in
    view = again.gbuffer.position[3:5]
    del again
    assert address(render_frame(compiled, image=False)) != first  # a view still holds the old one
    assert view.shape == (2, 24, 3)


def test_one_held_array_keeps_its_whole_zeroed_group_from_the_next_frame(tmp_path):
    """The arrays that start zero share one buffer, cleared in one memset (`CompiledScene.zeroed_group`):
    while a view holds any one of them, the next frame takes new memory for all, and the held values
    stay as they were."""
    compiled = compile_scene(textured_scene(tmp_path, "phong", 1))
    frame = render_frame(compiled, image=False)
    uv, position = frame.gbuffer.uv, frame.gbuffer.position.__array_interface__["data"][0]
    before = uv.copy()
    del frame
    again = render_frame(compiled, image=False)
    assert again.gbuffer.position.__array_interface__["data"][0] != position
    assert np.abs(before).sum() > 0 and np.array_equal(uv, before)
    second = again.gbuffer.position.__array_interface__["data"][0]
    del again
    assert render_frame(compiled, image=False).gbuffer.position.__array_interface__["data"][0] == second


@pytest.mark.parametrize("shading", ["phong", "gouraud"])
@pytest.mark.parametrize("beside", [False, True])
def test_what_a_user_wrote_into_a_dropped_gbuffer_does_not_reach_the_next_frame(tmp_path, monkeypatch, shading, beside):
    """beside: the reused arrays cleared on a pool thread while the z-buffer is drawn (`start_beside`,
    as from PASS_POOL_MIN_SAMPLES samples on a machine of several cores), not on the caller."""
    if beside:
        monkeypatch.delenv("DIFFLAB_THREADS", raising=False)
        monkeypatch.setattr(launch, "PASS_POOL_MIN_SAMPLES", 1)
        monkeypatch.setattr(launch, "cpu_threads", lambda: 3)
    scene = textured_scene(tmp_path, shading, 1)
    compiled = compile_scene(scene)
    frame = render_frame(compiled)
    address = frame.gbuffer.light_dir.__array_interface__["data"][0]
    for value in [frame.image, *fields(frame.gbuffer).values()]:
        if isinstance(value, np.ndarray) and value.flags.writeable:
            value[...] = 7
    del frame, value
    again = render_frame(compiled)
    assert again.gbuffer.light_dir.__array_interface__["data"][0] == address  # the same memory, written over
    fresh = render_frame(scene)
    assert np.array_equal(again.image, fresh.image)
    assert_same_gbuffer(again.gbuffer, fresh.gbuffer)


def test_camera_struct_is_built_once_per_camera_and_grid(tmp_path):
    camera = textured_scene(tmp_path, "phong", 1).camera
    assert camera_struct(camera, 24, 20) is camera_struct(camera, 24, 20)
    assert camera_struct(camera, 48, 40) is not camera_struct(camera, 24, 20)
    assert camera_struct(camera, 48, 40).width == 48
