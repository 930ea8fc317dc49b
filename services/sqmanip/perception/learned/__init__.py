"""Learned recognition (Ch. 3.3, 3.6.2, Appendix A): synthetic datasets, DSQNet / SQNet / DSQNet+,
the DGCNN segmentation network, their training and inference.

Modules: :mod:`.config` (dataclasses and presets), :mod:`.models` (networks, PCA pre-processing,
:func:`~.models.build_model`), :mod:`.losses`, :mod:`.datasets` (generation and loading),
:mod:`.train` (``sqmanip train <model>``), :mod:`.infer` (:class:`~.infer.NetworkRecognizer`).
Heavy modules are imported lazily by their users; this package imports nothing at load time.
"""
