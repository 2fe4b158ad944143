"""The paper's results from one command (``flatlab paper``) and the page that shows them.

* :mod:`.pipeline`: the stage registry (``stages.yaml``) and presets (``presets/*.yaml``) as data,
  cached / resumable runs, one results JSON per stage under ``docs/results/``;
* :mod:`.render`: ``docs/results.md``, its plots and the README's headline table, from those JSONs
  and the paper's numbers (``paper_numbers.json``);
* :mod:`.desk`: ``flatlab desk``, the five-object desk with the scripted expert.

A top layer (like ``cli``): it runs the other layers' commands as subprocesses.
"""
