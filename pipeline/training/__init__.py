"""The default classifier: its training datasets, annotations and the machine-wide model cache.

Modules:
    config: config section `training`.
    model: train the default model (a cached stage) and bind it to classify.
    model_cache: trained models shared by every store on the machine.
    datasets: simulated datasets on demand.
    annotations: annotation files beside field recordings.
"""
