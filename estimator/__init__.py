"""The particle estimator, by part: the SMC algorithm at this level (``filter``, the loop;
``resampling``, ``adaptive``, ``state``; ``collect``, ``belief`` and ``timeline``, what each update
reports; ``config``), the scene model and its mechanisms (``model``), the particle worlds
(``worlds``) and what is built on the belief (``applications``: hidden-object search, the Kalman
tracker, the person's view). A regular package, so that a copy of the project on ``PYTHONPATH`` is
imported whole, never mixed with an installed one."""
