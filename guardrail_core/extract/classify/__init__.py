"""§3.3 of Matsumoto et al. 2019: the sliced segments classified as guardrail or other by a
fine-tuned CNN on their crops, and their labels corrected by their neighbours.

Nothing is imported here: the parameters must load without torch. Each part is its own module:

The crop classifier (the paper's fine-tuned CNN)
    :mod:`.crop_classifier_params` (its classes, modes and :class:`ClassifierParams`),
    :mod:`.backbone` (the ImageNet-pretrained EfficientNet-Lite0, crop embeddings),
    :mod:`.cnn_runtime` (running it on ONNX Runtime or torch), :mod:`.torch_threads`,
    :mod:`.crop_classifier` (the trained model, :class:`GuardrailClassifier`),
    :mod:`.crop_classifier_training` (training it on labelled crops, held-out metrics),
    :mod:`.model_folder` (saving and loading a model folder).
The segment head (ours: a segment's shape fused with its crop)
    :mod:`.piece_chains` (a component's pieces followed slice to slice), :mod:`.shape_features`
    (what a segment's points say about it), :mod:`.segment_head` (the small network),
    :mod:`.model_training` (training sets of labelled segments; the crop classifier and the
    segment head trained together).
Classifying a window's segments
    :mod:`.segment_scores` (asking the CNN only where the shape leaves the label open).
Label correction
    :mod:`.label_correction` (the paper's rules, and ours in order), with
    :mod:`.label_correction_params`, :mod:`.segment_extents` (where segments lie, which touch),
    :mod:`.behind_a_rail`, :mod:`.wireframe_objects` and :mod:`.crop_veto` (the rules beyond
    the paper).
Both, as ``guardrail process`` and re-predicting a run do them
    :mod:`.score_and_correct`.
"""
