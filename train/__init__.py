"""IPPO trainer for ColorGrid (needs torch). Entry points: ``colorgrid train``, ``python -m train``.

Modules: ``config`` (frozen settings and presets), ``nets`` (paper and fast actor-critics),
``ppo`` (GAE and losses), ``learner`` (one agent's rollout buffer and update), ``trainer``
(the loop), ``checkpoint`` (files), ``policy`` (trained nets behind the common Policy
interface), ``metrics`` (CSV/JSONL/TensorBoard), ``cli``.
"""
