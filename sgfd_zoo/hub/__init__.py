"""The zoo's runs on the Hugging Face Hub: ``sgfd-zoo push-to-hub`` and ``sgfd-zoo load-from-hub``.

A repository holds what rl-zoo3's own ``push_to_hub`` puts there, under the names its ``load_from_hub`` reads, and
the evaluation of every split:

    <algo>-<EnvName>.zip      the final model, as the run saved it
    config.yml, args.yml      the run's hyperparameters and arguments (args.yml: its log folder's name only, no
                              URL's credentials)
    env_kwargs.yml            the env settings it trained with
    vec_normalize.pkl         its normalisation statistics, when it has some
    train_eval_metrics.zip    its evaluations during training (rl-zoo3's evaluations.npz and one per split),
                              monitor files and logs
    results.json              the final model's evaluation on every split, with each split's domains
    README.md                 the model card; its metadata holds one result per split
    replay.mp4                a video of the agent on an unseen split (sgfd-zoo record-video's)

Pushing uses huggingface_hub's ``HfApi`` (the pinned version), with the token of ``hf auth login`` or ``HF_TOKEN``;
``--dry-run FOLDER`` writes exactly these files there and uploads nothing. Loading takes them from the Hub or from a
local copy (``--from-dir``) into a new run folder of a log folder, where ``enjoy``, ``record-video`` and ``evaluate``
find it.
"""

#: The files of a repository, by role (the model's name depends on the run: :func:`model_file`)
CONFIG, ARGS, ENV_KWARGS = "config.yml", "args.yml", "env_kwargs.yml"
VEC_NORMALIZE, METRICS, RESULTS, CARD, VIDEO = (
    "vec_normalize.pkl",
    "train_eval_metrics.zip",
    "results.json",
    "README.md",
    "replay.mp4",
)


def model_file(algo: str, env_name: str) -> str:
    """rl-zoo3's name of a model in a repository: ``<algo>-<EnvName>.zip`` (huggingface_sb3's ``ModelName``)."""
    return f"{algo}-{env_name}.zip"


def repository_id(organization: str, repo_name: str | None, model: str) -> str:
    """``<organization>/<name>`` of a run's repository, the name by default the model's file name without ``.zip``.

    :param organization: the Hub user or organization (``-orga``)
    :param repo_name: the repository's name (``-name``), or None
    :param model: the model's file name (:func:`model_file`)
    """
    return f"{organization}/{repo_name or model.removesuffix('.zip')}"
