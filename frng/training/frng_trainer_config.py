"""The config sections F-RNG's trainer (:mod:`frng.training.frng_trainer`, ``frng train``) reads: ``train``
(:class:`TrainConfig`: steps, seeds, optimiser, the L_2 settings, checkpoints) and ``train.loss`` (:class:`LossConfig`:
the loss weights), each key declared on its field (:func:`frng.plan.sections.key`)."""

from __future__ import annotations

from dataclasses import dataclass

from frng.plan.sections import FINITE, key, register


@register("train.loss")
@dataclass(frozen=True)
class LossConfig:
    """The config's ``train.loss`` section: the loss weights (each key declared on its field)."""

    CONFIG_DOC = "paper (lambda_c, lambda_kld, lambda_1, lambda_per) = (0.2, 0.2, 1.0, 0.5)"

    lambda_1: float = key(
        1.0,
        "weight of L_2 (paper 1.0)",
        type="number",
        minimum=0,
    )
    lambda_alpha: float = key(
        0.0,
        "not in the paper: weight of an alpha squared error per covered pixel (frng.training.frng_trainer.alpha_loss)",
        type="number",
        minimum=0,
    )
    lambda_depth: float = key(
        0.0,
        "not in the paper: weight of an L1 between the depth head's moved coarse Gaussians' distances along their "
        "input rays and the input views' G-buffer distances (`frng.training.frng_trainer.depth_loss`; the training split's "
        "G-buffers, read only when > 0 and `frng.depth_head` > 0). Without it the rasterizer's gradient moves them "
        "~0.01. Scratch, 2026-12-01, at 1.0 on the 2026-11-30 reproduction's caches: the head learns the backbone's "
        "bias (depth error 0.062-0.079 -> 0.042-0.043 on three procedural test objects) but not the thin book or the "
        "caddy (0.198 -> 0.214, 0.120 -> 0.135); PSNR +0.15 [0.04, 0.27], SSIM -0.0075 [-0.014, -0.0003], LPIPS "
        "+0.0016 [-0.0005, +0.0035]: off by default",
        type="number",
        minimum=0,
    )
    lambda_per: float = key(
        0.5,
        "weight of L_per (paper 0.5)",
        type="number",
        minimum=0,
    )
    lambda_c: float = key(
        0.2,
        "weight of L_ind's cosine term (paper lambda_c 0.2)",
        type="number",
        minimum=0,
    )
    lambda_kld: float = key(
        0.2,
        "weight of L_ind's KL term (paper lambda_KLD 0.2)",
        type="number",
        minimum=0,
    )
    temperature: float = key(
        1.0,
        "softmax temperature turning material tokens into distributions for the KL term",
        type="number",
        exclusiveMinimum=0,
    )
    ind_pixels: bool = key(
        True,
        "not in the paper's form: L_ind also compares the per-Gaussian material the renderer reads (decoder features, "
        "or the decoded GGX parameters of the Cook-Torrance ablation), rebuilt from the same input views photographed "
        "under the object's second input light (needs `render.input_lights` >= 2; else T_mat only). Measured "
        "(0f613d7's data, 800 steps): +0.03 dB [0.00, 0.07] over T_mat only; z-scored payloads (stronger) -0.45 dB; "
        "on raw GGX logits it cost the Cook-Torrance ablation 1.2 dB (docs/studies/2026-11-26-what-limits-frng.md)",
        type="boolean",
    )


@register("train")
@dataclass(frozen=True)
class TrainConfig:
    """The config's ``train`` section (each key declared on its field)."""

    CONFIG_DOC = "F-RNG training (frng/training/frng_trainer.py, `frng train`)"

    steps: int = key(
        300,
        "steps of the full model",
        type="integer",
        minimum=1,
        maximum=10000000,
    )
    seeds: tuple[int, ...] = key(
        [0],
        "training seeds of `full` and the ablations: the plain variant names train with the models' seed "
        "(`train_seed`, else `seed`); every other seed listed adds `{variant}@s{seed}` (trained with `train_seed` = "
        "that seed, relit and evaluated beside it, `results/models/full@s1/` etc.); `vs_backbone` and `ablation` "
        "average over the seeds and report the seed spread. The K and #views sweeps are not repeated. Read while "
        "planning (`frng/plan/variants.py`); changing it retrains nothing already trained",
        type="array",
        items={"type": "integer", "minimum": 0},
        minItems=1,
        uniqueItems=True,
    )
    ablation_steps: int | None = key(
        None,
        "steps of every other variant (null: `steps`); null at the default and paper tiers (every variant the full "
        "model's budget), 8 at the smoke tier",
        type=["integer", "null"],
        minimum=1,
        maximum=10000000,
    )
    lr: float = key(
        0.001,
        "AdamW's peak learning rate: linear warm-up, then cosine decay to 10%",
        type="number",
        exclusiveMinimum=0,
        maximum=10,
        **FINITE,
    )
    warmup: int = key(
        20,
        "steps of the linear learning-rate warm-up",
        type="integer",
        minimum=0,
        maximum=10000000,
    )
    weight_decay: float = key(
        0.01,
        "AdamW's weight decay",
        type="number",
        minimum=0,
    )
    grad_clip: float = key(
        1.0,
        "gradient-norm clip",
        type="number",
        exclusiveMinimum=0,
    )
    batch: int = key(
        1,
        "objects per step (split over ranks under torchrun/srun)",
        type="integer",
        minimum=1,
        maximum=1024,
    )
    target_views: int = key(
        2,
        "target views rendered per object and step (target light uniform over the object's target lights and other "
        "input lights)",
        type="integer",
        minimum=1,
        maximum=64,
    )
    target_lights: int = key(
        1,
        "target lights per object and step at the same target views: the views are rasterized once and shaded and "
        "scored under each light (the sampled one and others rendered at the same cameras; the paper leaves its "
        "batches open)",
        type="integer",
        minimum=1,
        maximum=16,
    )
    views: int = key(
        6,
        "input views (the cached rig entry)",
        type="integer",
        minimum=1,
        maximum=64,
    )
    perceptual_net: str = key(
        "vgg",
        "LPIPS backbone of L_per (the default and smoke tiers use alex, the backbone's and the metric's net: 16x "
        "cheaper than vgg at 64 px, `frng bench perceptual`)",
        type="string",
        enum=["vgg", "alex"],
    )
    perceptual_after: int = key(
        0,
        "L_per is switched on from this step on",
        type="integer",
        minimum=0,
        maximum=10000000,
    )
    background: tuple[float, ...] = key(
        [1.0, 1.0, 1.0],
        "linear colour renders and targets are composited over for L_2 and L_per (white, as `eval.background`: the "
        "background showing through a too-thin silhouette is penalised)",
        type="array",
        items={"type": "number", "minimum": 0},
        minItems=3,
        maxItems=3,
    )
    l2_space: str = key(
        "display",
        "where L_2 compares render and target: gamma-encoded (display) or linear. Monte-Carlo noise in a render "
        "biases a display-space L_2 towards over-bright renders (the gamma curve is concave); linear is unbiased",
        type="string",
        enum=["display", "linear"],
    )
    l2_pixels: str = key(
        "target",
        "pixels L_2 averages over: the target's foreground (alpha > 0.5, the metric's mask) or the union with the "
        "render's foreground. With union, pixels the frozen geometry over-covers show the white background in the "
        "target and pull every colour brighter (renders 1.2-1.3x too bright; docs/model-and-training.md)",
        type="string",
        enum=["target", "union"],
    )
    bf16: bool = key(
        True,
        "bf16 autocast of the networks where the hardware has bf16 (CUDA, CPUs with AMX/AVX512-BF16; elsewhere "
        "float32: emulated bf16 was 8x slower on an AVX2 CPU)",
        type="boolean",
    )
    checkpoint_every: int = key(
        25,
        "resumable checkpoint period (a rerun continues from it)",
        type="integer",
        minimum=1,
        maximum=10000000,
    )
    loss: LossConfig = key({})

    def __post_init__(self):
        object.__setattr__(self, "background", tuple(float(c) for c in self.background))
        object.__setattr__(self, "seeds", tuple(int(c) for c in self.seeds))

    def steps_for(self, variant: str) -> int:
        return self.steps if variant == "full" or self.ablation_steps is None else self.ablation_steps
