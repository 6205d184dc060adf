"""The tiny configuration several chain tests build on (test_ray, test_signals, test_memory_budget;
test_end_to_end takes its evaluate and report settings over the smoke run's upstream): one scan,
small images, a one-epoch classifier and a small population with two ablations. Tests that need it even
smaller merge their changes on top (``pipeline.infra.config.merge``)."""

TINY = {
    "data": {"scans": ["Home_001_1"],
             "synthetic": {"instances_per_scan": 0, "angle_step_deg": 30, "bigbird_width": 200,
                           "bigbird_height": 160, "avd_width": 480, "avd_height": 270}},
    "classifier": {"input_size": 64,
                   "training": {"train_images": 48, "val_images": 24, "epochs": 1, "batch_size": 16,
                                "min_accuracy": 0.0}},
    "features": {"n_samples": 3, "max_difficulty": 5, "batch_size": 32},
    "models": {"restarts": 0},
    "evaluate": {"track_length": 4, "max_difficulty": 5, "tracks_per_target": 2, "n_candidates": 3,
                 "bootstrap": 200, "ablations": ["models.noise_floor=dropout", "evaluate.test_domain_variance=cross_fit"],
                 "biased": {"n_loc_samples": 5},
                 "randomized": {"sigmas_m": [0.1, 0.3], "realizations": 6, "n_loc_samples": 5},
                 "sensitivity": {"sigmas_m": [0.1, 0.4], "realizations": 3, "n_loc_samples": 4},
                 "bias_maps": {"steps": 5}},
    "report": {"strict": "all"},   # tests and CI: a figure-text slip fails the build too
}
