"""The model levels behind the one stepping contract (`base.Model`): ideal, jones2016, fu2018.

.. include:: ../../docs/model.md
"""
