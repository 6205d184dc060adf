"""The classifier's training loop: batched augmentation, the freed-memory setting, the time split."""
import ctypes

import numpy as np
import pytest
import torch

from loaders.synthetic.source_domain import TRAIN_STREAM, render_set
from pipeline.infra import memory
from pipeline.scoring.alexnet import build_alexnet, init_for_training
from pipeline.scoring.training import augment, shrink, train_classifier
from pipeline.scoring.crops import to_tensor

pytestmark = pytest.mark.slow  # runs real stages (make test-fast skips it)

MEAN, STD = (0.485, 0.456, 0.406), (0.229, 0.224, 0.225)


def augment_one_by_one(xb, gen, mean, std):
    """The augmentation written plainly, image by image: quarter turn, then mirror, then
    normalise, then contrast c and brightness b (the same draws in the same order)."""
    n = len(xb)
    k, flip = gen.integers(0, 4, n), gen.random(n) < 0.5
    c = torch.from_numpy(gen.uniform(0.8, 1.2, n).astype(np.float32))
    b = torch.from_numpy(gen.uniform(-0.2, 0.2, n).astype(np.float32))
    out = []
    for i in range(n):
        img = np.rot90(xb[i], k[i])
        img = img[:, ::-1] if flip[i] else img
        out.append(to_tensor(np.ascontiguousarray(img), mean, std)[0] * c[i] + b[i])
    return torch.stack(out)


def test_batched_augmentation_equals_the_image_by_image_one_bit_for_bit():
    """Same draws, same float32 roundings: a seed's trained weights do not depend on the batching."""
    x = np.random.default_rng(0).integers(0, 256, (40, 16, 16, 3), dtype=np.uint8)
    x[:, 0, :3] = 255  # a marked corner, so every turn and mirror is distinguishable
    got = augment(x, np.random.default_rng(4), MEAN, STD)
    ref = augment_one_by_one(x, np.random.default_rng(4), MEAN, STD)
    assert got.shape == (40, 3, 16, 16) and got.dtype == torch.float32
    assert got.is_contiguous(memory_format=torch.channels_last)
    assert torch.equal(got, ref)


def test_augmentation_rejects_non_uint8_images():
    with pytest.raises(ValueError, match="uint8"):
        augment(np.zeros((2, 8, 8, 3), np.float32), np.random.default_rng(0), MEAN, STD)


def _glibc_with_mallinfo2() -> bool:
    return memory._libc() is not None and hasattr(memory._libc(), "mallinfo2")


@pytest.mark.skipif(not _glibc_with_mallinfo2(), reason="not glibc >= 2.33: nothing to tune or to inspect")
def test_freed_memory_setting_is_restored_and_does_not_change_the_weights(monkeypatch):
    """Two trainings, one with the heap keeping freed blocks and one without, give byte-identical
    weights; inside the block a large allocation comes from the heap, after it from mmap again."""
    x, y = render_set(24, 64, 12, seed=1, stream=TRAIN_STREAM)
    states, split = [], {}
    for keep in (memory.KEEP_THRESHOLD, memory.DEFAULT_THRESHOLD):
        monkeypatch.setattr(memory, "KEEP_THRESHOLD", keep)
        m = init_for_training(build_alexnet(12, 0.5), 3)
        train_classifier(m, x, y, epochs=1, batch_size=12, lr=1e-4, weight_decay=0.0, warmup_steps=1,
                         seed=3, mean=MEAN, std=STD, progress=False, split=split)
        states.append(m.state_dict())
    # the loop's time split, as the stage records it in card.json
    assert set(split) == {"augment_s", "forward_s", "backward_s", "optimizer_s"}
    assert all(v >= 0 for v in split.values()) and split["backward_s"] > 0
    assert all(torch.equal(states[0][k], states[1][k]) for k in states[0])
    monkeypatch.undo()

    libc = ctypes.CDLL("libc.so.6")
    libc.malloc.restype, libc.free.argtypes = ctypes.c_void_p, [ctypes.c_void_p]

    class MallInfo2(ctypes.Structure):  # glibc's struct mallinfo2: ten size_t counters
        _fields_ = [(f, ctypes.c_size_t) for f in ("arena", "ordblks", "smblks", "hblks", "hblkhd",
                                                   "usmblks", "fsmblks", "uordblks", "fordblks", "keepcost")]
    libc.mallinfo2.restype = MallInfo2

    def own_mmap() -> bool:
        """Is a block larger than all free heap space (so no free chunk can serve it) given its
        own mmap, rather than grown from the heap?"""
        info = libc.mallinfo2()
        before = info.hblks
        p = libc.malloc(info.fordblks + (64 << 20))
        mapped = libc.mallinfo2().hblks == before + 1
        libc.free(p)
        return mapped

    with memory.reuse_freed_memory() as ok:
        assert ok and not own_mmap()
    assert own_mmap()


def test_shrink_resizes_a_batch_and_keeps_it_channels_last():
    x = augment(np.random.default_rng(0).integers(0, 256, (4, 32, 32, 3), dtype=np.uint8),
                np.random.default_rng(1), MEAN, STD)
    y = shrink(x, 20)
    assert y.shape == (4, 3, 20, 20) and y.is_contiguous(memory_format=torch.channels_last)
    # an area-like filter: a flat image stays flat, and a batch of the size asked is returned as is
    flat = torch.full((2, 3, 32, 32), 0.7).contiguous(memory_format=torch.channels_last)
    assert torch.allclose(shrink(flat, 20), torch.tensor(0.7), atol=1e-6)
    assert shrink(x, 32) is x


def test_early_epochs_train_on_shrunk_batches_then_on_full_ones():
    """Progressive resizing: the network sees early_size inputs in the first early_epochs epochs
    and the rendered size after; the last epoch is always at the rendered size, and early_epochs = 0
    or an early_size not below the rendered one leaves every step there."""
    x, y = render_set(24, 80, 12, seed=1, stream=TRAIN_STREAM)
    for early, size, expect in ((2, 64, [64, 64, 64, 64, 80, 80]), (9, 64, [64, 64, 64, 64, 80, 80]),
                                (0, 64, [80] * 6), (2, 96, [80] * 6)):
        m = init_for_training(build_alexnet(12, 0.5), 3)
        seen = []
        m.features[0].register_forward_pre_hook(lambda mod, inp: seen.append(inp[0].shape[-1]))
        train_classifier(m, x, y, epochs=3, batch_size=12, lr=1e-4, weight_decay=0.0, warmup_steps=1,
                         seed=3, mean=MEAN, std=STD, progress=False, early_epochs=early, early_size=size)
        assert seen == expect


def test_early_epochs_crop_and_take_the_early_forward_then_the_full_network():
    """early_mode = "crop": the early epochs see early_size squares and run early_forward (the
    compact head), the last epochs the rendered size through the network's own forward."""
    from pipeline.scoring.alexnet import compact_forward

    x, y = render_set(24, 80, 12, seed=1, stream=TRAIN_STREAM)
    m = init_for_training(build_alexnet(12, 0.5), 3)
    seen, early_calls = [], []
    m.features[0].register_forward_pre_hook(lambda mod, inp: seen.append(inp[0].shape[-1]))

    def counted(model, xb):
        early_calls.append(xb.shape[-1])
        return compact_forward(model, xb)

    train_classifier(m, x, y, epochs=3, batch_size=12, lr=1e-4, weight_decay=0.0, warmup_steps=1, seed=3,
                     mean=MEAN, std=STD, progress=False, early_epochs=2, early_size=64, early_mode="crop",
                     early_forward=counted)
    assert seen == [64, 64, 64, 64, 80, 80] and early_calls == [64] * 4
    with pytest.raises(ValueError, match="early_mode"):
        train_classifier(m, x, y, epochs=1, batch_size=12, lr=1e-4, weight_decay=0.0, warmup_steps=1,
                         seed=3, mean=MEAN, std=STD, progress=False, early_mode="zoom")
