"""The soak: random valid scenarios drawn over the whole schema (``draw_scenario``, with
``draw_obstacles``), run as ``taskcam run`` runs them (``scenes``), and their run
directories audited against what the run says it did (``audit``: ``audit_robot``,
``audit_scene``, ``audit_findings``). docs/soak.md says what each finding means."""
