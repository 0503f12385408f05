"""The code MLflow runs to build a logged policy's :class:`~diana_lab.tracking.pyfunc_model.PolicyModel` when it loads
it (MLflow's "models from code"): the model holds this file, not a pickled object. Imported by nothing in the package.
"""

from mlflow.models import set_model

from diana_lab.tracking.pyfunc_model import PolicyModel

set_model(PolicyModel())
