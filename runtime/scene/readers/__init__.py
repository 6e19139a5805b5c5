"""Volume file readers, one module per format; :mod:`photon_fields.runtime.scene.volume_io` picks one by suffix.

Each reader returns ``(array indexed [x, y, z], spacing from the file or None, window from the file or None)``
(:data:`photon_fields.runtime.scene.readers.params.ReadResult`) and raises a one-line
:class:`photon_fields.runtime.errors.InputError` naming the file for every problem it recognizes; the
dispatcher turns any other exception into one such line and normalizes the array with ``make_volume``.
"""
