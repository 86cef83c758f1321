"""Running a capture: the job that renders the planned frames (``job``) under the capture's render settings
(``render_settings``), the panel's timer task (``task``) and the merge of a farm's shards (``merge``)."""
