# Copyright 2026 The mlsemreg_ros Authors
#
# Licensed under the Apache License, Version 2.0 (the "License");
# you may not use this file except in compliance with the License.
# You may obtain a copy of the License at
#
#     http://www.apache.org/licenses/LICENSE-2.0
#
# Unless required by applicable law or agreed to in writing, software
# distributed under the License is distributed on an "AS IS" BASIS,
# WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
# See the License for the specific language governing permissions and
# limitations under the License.
"""
The stages of a pair registration, one module each, run in order by ``Registration.register``.

A stage reads and writes one :class:`~mlsemreg_ros.core.stages.context.RegistrationContext`;
the loop times it and hands the candidates it returns to the confidence rule
(docs/architecture.md, docs/extending.md). The stages call the algorithms of
``core/matching``, ``core/estimation`` and ``core/alignment``; they hold no algorithm of
their own.
"""
