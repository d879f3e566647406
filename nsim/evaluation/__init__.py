"""How real the simulation is: ground truth, tables, and the evaluation artifact's files.

``nsim evaluate`` (``nsim.stages.evaluate``) only resolves inputs, calls and publishes; the work is here:

``evaluate_config``  the stage's settings (``Config``: table, cameras, LPIPS, depth range, SLAM, detection)
``renders``          the renders scored (``load_render``), their lineage, reading their frames; ``ArtifactReader``
``inputs``           what the stage resolves for an evaluation (``EvaluationInputs``: renders, device, seed...)
``truth``            ground truth as an interface (``GroundTruth``) and the pairs it yields
``oracle_truth``     ``OracleTruth``: the test room's oracle at the rendered poses (poses / trajectory renders)
``recording_truth``  ``RecordingTruth``: a robot's recording and its registration (recording-mode renders)
``evaluate_tables``  ``Evaluation``, its ground truth chosen by the renders' mode (``truth_for``), and one
                     function per table over the pairs that ground truth gives (``compute``)
``write``            the artifact's files: table, records, plots, trajectories (``write_result``)

Metrics themselves live in ``nsim.metrics`` and the paper's table layouts in
``nsim.metrics.paper_tables``; nothing here defines a metric.
"""
