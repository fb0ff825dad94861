"""One application function per command of ``jaxanom``: each owns its sequence and its checks.

``fit_stats.fit_stats``, ``evaluate.evaluate``, ``predict.predict``, ``score.score``,
``train.train``, ``convert_weights.convert_weights`` and ``demo.demo`` take the command's
settings as keyword arguments, refuse bad input with ``jaxanom.errors.InputError`` naming the
argument (the command line says its flag), write into outputs claimed by ``jaxanom.app.outputs``
and print what the command reports. ``jaxanom.cli`` only parses flags and calls them.
"""
