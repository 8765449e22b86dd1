"""What a rig log's metadata records about the rig and the run (the header of a ``rig-log v1`` file).

One definition for every writer of a log: ``rig run`` (:mod:`rig.commands.run`), ``rig demo``
(:mod:`rig.demo`), the trace importer (:mod:`rig.trace_import`) and the benchmarks.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from identify import __version__
from identify.experiment_record import ExperimentMetadata

if TYPE_CHECKING:
    from rig.experiment_config import Excitation
    from rig.rig_config import RigConfig
    from sim_backend.plant import SimulatedGearbox

__all__ = ["experiment_log_metadata", "rig_config_metadata"]


def rig_config_metadata(config: RigConfig) -> dict[str, Any]:
    """The rig config as a log's metadata records it (``config["rig"]``): file, name, URL, rate, transport
    options, drive scaling, limits and encoder."""
    return {"file": config.source, "name": config.name, "url": config.url, "sample_rate_hz": config.sample_rate_hz,
            "options": config.options, "drive_counts_per_revolution": config.drive.counts_per_revolution,
            "limits": {"position_min_rad": config.limits.position_min_rad,
                       "position_max_rad": config.limits.position_max_rad,
                       "rate_max_rad_per_s": config.limits.rate_max_rad_per_s},
            "encoder": {"bits": config.encoder.bits, "multi_turn_bits": config.encoder.multi_turn_bits,
                        "signed": config.encoder.signed, "direction": config.encoder.direction,
                        "offset_counts": config.encoder.offset_counts}}


def experiment_log_metadata(config: RigConfig, excitation: Excitation, gearbox: SimulatedGearbox | None,
                            num_samples: int, sim_faults: dict[str, Any] | None = None) -> ExperimentMetadata:
    """The metadata of a log of ``num_samples`` samples of ``excitation`` on the rig of ``config`` (and the
    simulated ``gearbox``, if any, with the ``--sim-faults`` SPEC and seed it injected)."""
    rig_config = rig_config_metadata(config)
    values: dict[str, Any] = {}
    if gearbox is not None:
        from sim_backend.plant_config import describe_noise

        values = {"noise_kind": gearbox.noise.kind,
                  "noise_bound_rad": gearbox.noise.noise_bound_rad + gearbox.encoder.quantization_bound_rad,
                  "seed": gearbox.seed}
        assert config.simulation is not None  # a simulated gearbox runs only on a config with [simulation]
        rig_config["simulation"] = {"plant": str(config.simulation.plant_path), "noise": describe_noise(gearbox.noise)}
        if sim_faults is not None:
            rig_config["simulation"]["faults"] = sim_faults
    return ExperimentMetadata(
        sample_period_s=config.sample_period_s, source=config.name, transport=config.url,
        encoder_bits=config.encoder.bits, excitation=excitation.name, excitation_seed=excitation.seed,
        config={"rig": rig_config, "excitation": excitation.metadata(), "num_samples": num_samples,
                "excitation_samples": excitation.cycle_samples,  # cut or repeated cyclically to num_samples
                "excitation_repeat": excitation.repetition},
        software_version=__version__, **values)
